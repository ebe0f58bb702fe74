"""``/healthz``, ``/examples`` and the dashboard page."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, status
from fastapi.responses import FileResponse, JSONResponse

from service.api.deps import ServicesDep
from service.api.schemas import Examples, ExampleView, Health

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
"""The dashboard's files (``service/static``)."""

router = APIRouter()


@router.get(
    "/healthz",
    tags=["system"],
    response_model=Health,
    responses={503: {"model": Health, "description": "A dependency is down."}},
)
def healthz(deps: ServicesDep) -> JSONResponse:
    """The API, the database and the broker: 200 when all are ok, else 503. The answer is
    the last probe of the app's health monitor (every ``LTLNAV_HEALTH_PROBE_SECONDS``), so a
    health check opens no connection."""
    result = deps.health.current()
    report = Health(
        status="ok" if result.ok else "degraded",
        api="ok",
        database=result.database,
        broker=result.broker,
        open=not deps.settings.api_keys,
        problems=dict(result.problems),
    )
    code = status.HTTP_200_OK if result.ok else status.HTTP_503_SERVICE_UNAVAILABLE
    return JSONResponse(report.model_dump(), status_code=code)


@router.get("/examples", tags=["system"], response_model=Examples)
def examples(deps: ServicesDep) -> Examples:
    """The bundled example missions (submit one with ``{"example": name}``)."""
    return Examples(
        examples=[
            ExampleView(name=e.name, task=e.spec.task, robot=e.spec.robot.model)
            for e in deps.examples.all()
        ]
    )


@router.get("/", include_in_schema=False)
def dashboard() -> FileResponse:
    """The dashboard page (``service/static/index.html``)."""
    page = STATIC_DIR / "index.html"
    if not page.is_file():
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, "the dashboard is not installed; the API is at /docs"
        )
    return FileResponse(page, media_type="text/html")
