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
from hypothesis.errors import Unsatisfiable
from schemathesis import Case, GenerationMode
from schemathesis.core.errors import InvalidSchema
from schemathesis.core.result import Ok
from schemathesis.schemas import BaseSchema

from service.api import health
from service.api.app import create_app
from service.db import Database, upgrade
from tests.service.api_helpers import RecordingEnqueue, bearer, settings_for, tiny

EXAMPLES = 60
"""Examples per operation and generation mode (11 operations: 5-10 s per mode here, a few times
that when the machine is busy)."""


@pytest.fixture(scope="module")
def api_schema(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BaseSchema]:
    tmp_path: Path = tmp_path_factory.mktemp("fuzz")
    url = f"sqlite:///{tmp_path / 'ltlnav.db'}"
    upgrade(url)
    database = Database(url)
    app = create_app(settings_for(tmp_path, url, keys=["fuzz-key"]), RecordingEnqueue(database))
    http = TestClient(app, headers=bearer("fuzz-key"))
    mission_id = http.post("/missions", json=tiny()).json()["id"]
    # A final mission: an event stream of it that the fuzzer might open ends at once.
    http.post(f"/missions/{mission_id}/cancel")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(health, "broker_state", lambda settings: ("ok", None))
        yield schemathesis.openapi.from_asgi("/openapi.json", app)
    database.dispose()


def _fuzz(strategy: st.SearchStrategy[Case]) -> None:
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
        for headers in (bearer("fuzz-key"), None):
            response = case.call(headers=headers)
            assert response.status_code < 500, (
                f"{case.method} {case.formatted_path} -> {response.status_code}: "
                f"{response.text[:500]}"
            )

    check()


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE])
def test_no_server_errors(api_schema: BaseSchema, mode: GenerationMode) -> None:
    results = list(api_schema.get_all_operations())
    operations = [result.ok() for result in results if isinstance(result, Ok)]
    assert len(operations) == len(results), "the schema has operations schemathesis cannot read"
    assert len(operations) == 11, [f"{op.method} {op.path}" for op in operations]
    fuzzed = []
    for operation in operations:
        try:
            _fuzz(operation.as_strategy(mode))
        except Unsatisfiable:
            # Only negative mode: an operation without parameters or body has nothing to
            # break, and every draw of its negated schema fails.
            assert mode == GenerationMode.NEGATIVE, operation.label
            continue
        fuzzed.append(operation.label)
    assert len(fuzzed) >= (11 if mode == GenerationMode.POSITIVE else 8), fuzzed
