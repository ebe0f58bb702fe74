"""A small HTTP client of the service's API (httpx), used by ``ltlnav submit``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx

FINAL = frozenset({"done", "failed", "cancelled"})


class ServiceError(Exception):
    """A 4xx/5xx answer, or the service cannot be reached; the message is for the user."""

    def __init__(self, message: str, status: int | None = None) -> None:
        self.status = status
        super().__init__(message)


def _describe(response: httpx.Response) -> str:
    try:
        detail = response.json().get("detail")
    except ValueError:
        detail = response.text.strip() or response.reason_phrase
    if isinstance(detail, list):
        lines = []
        for problem in detail:
            where = problem.get("field") or ".".join(str(p) for p in problem.get("loc", []))
            lines.append(f"  {where}: {problem.get('msg')}")
        return "\n".join(lines)
    return str(detail)


class ServiceClient:
    """The API at ``base_url``, authenticating with ``api_key`` when given."""

    def __init__(self, base_url: str, api_key: str | None = None, timeout: float = 30.0) -> None:
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self.base_url = base_url.rstrip("/")
        self._http = httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout)

    def __enter__(self) -> ServiceClient:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.HTTPError as error:
            raise ServiceError(f"cannot reach the service at {self.base_url}: {error}") from error
        if response.status_code >= 400:
            raise ServiceError(
                f"{method} {path} -> {response.status_code}:\n{_describe(response)}",
                response.status_code,
            )
        return response

    def submit(self, document: Any) -> dict[str, Any]:
        """POST a mission document (or ``{"example": name}``); the ``{id, status, links}``."""
        created: dict[str, Any] = self._request("POST", "/missions", json=document).json()
        return created

    def mission(self, mission_id: str) -> dict[str, Any]:
        """GET one mission."""
        found: dict[str, Any] = self._request("GET", f"/missions/{mission_id}").json()
        return found

    def cancel(self, mission_id: str) -> dict[str, Any]:
        """Request a cooperative cancel."""
        found: dict[str, Any] = self._request("POST", f"/missions/{mission_id}/cancel").json()
        return found

    def wait(
        self,
        mission_id: str,
        on_update: Callable[[dict[str, Any]], None] | None = None,
        poll_seconds: float = 1.0,
    ) -> dict[str, Any]:
        """Poll the mission until it is final, calling ``on_update`` with each reading."""
        while True:
            mission = self.mission(mission_id)
            if on_update is not None:
                on_update(mission)
            if mission["status"] in FINAL:
                return mission
            time.sleep(poll_seconds)

    def download_bundle(self, mission_id: str, path: Path) -> Path:
        """Save the mission's bundle zip at ``path`` (written whole or not at all)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(path.name + ".part")
        try:
            with self._http.stream("GET", f"/missions/{mission_id}/bundle") as response:
                if response.status_code >= 400:
                    response.read()
                    raise ServiceError(
                        f"bundle -> {response.status_code}: {_describe(response)}",
                        response.status_code,
                    )
                with partial.open("wb") as out:
                    for chunk in response.iter_bytes():
                        out.write(chunk)
        except httpx.HTTPError as error:
            partial.unlink(missing_ok=True)
            raise ServiceError(f"downloading the bundle failed: {error}") from error
        partial.replace(path)
        return path
