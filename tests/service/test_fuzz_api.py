"""Schemathesis against the app's own ``/openapi.json``: positive and negative inputs for
every operation, each sent with and without the API key; no request may give a 5xx. The
enqueue is a fake; the database is a SQLite file holding one real mission."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st
from schemathesis import Case, GenerationMode
from schemathesis.core.errors import InvalidSchema
from schemathesis.schemas import BaseSchema

from service.api import health
from service.api.app import create_app
from service.db import Database, upgrade
from tests.service.api_helpers import RecordingEnqueue, bearer, settings_for, tiny

EXAMPLES = 150
"""Examples per generation mode over all operations (about 20 s each here)."""


@pytest.fixture(scope="module")
def api_schema(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BaseSchema]:
    tmp_path: Path = tmp_path_factory.mktemp("fuzz")
    url = f"sqlite:///{tmp_path / 'ltlnav.db'}"
    upgrade(url)
    database = Database(url)
    app = create_app(settings_for(tmp_path, url, keys=["fuzz-key"]), RecordingEnqueue(database))
    TestClient(app).post("/missions", json=tiny(), headers=bearer("fuzz-key"))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(health, "broker_state", lambda settings: ("ok", None))
        yield schemathesis.openapi.from_asgi("/openapi.json", app)
    database.dispose()


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE])
def test_no_server_errors(api_schema: BaseSchema, mode: GenerationMode) -> None:
    seen: set[str] = set()
    strategy = api_schema.as_strategy(mode)

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def check(data: st.DataObject) -> None:
        try:
            case: Case = data.draw(strategy)
        except InvalidSchema:
            # Schemathesis sometimes cannot negate a schema ("Cannot generate an array with 1
            # demanded elements"): a generator limit, not a finding about the API.
            reject()
        seen.add(f"{case.method} {case.path}")
        for headers in (bearer("fuzz-key"), None):
            response = case.call(headers=headers)
            assert response.status_code < 500, (
                f"{case.method} {case.formatted_path} -> {response.status_code}: "
                f"{response.text[:500]}"
            )

    check()
    assert len(seen) >= 8, seen
