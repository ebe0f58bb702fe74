"""What keeps reads of the API fast while it validates submissions and the workers train: the
API process never loads the learners, leaves its start-up objects out of the garbage
collector's reach, validates one submission at a time, times itself in ``Server-Timing``; the
worker yields the CPU."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.submission_gate import SubmissionGate
from service.db import Database, upgrade
from service.jobs.priority import autogroup_nice
from tests.service.api_helpers import RecordingEnqueue, settings_for, tiny

ROOT = Path(__file__).resolve().parents[2]


def _run_python(code: str) -> str:
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_the_api_process_does_not_load_torch_or_the_learners() -> None:
    # torch and stable-baselines3 add seconds of start-up and some 170,000 objects that every
    # full garbage collection of the API process walks.
    code = (
        "import sys; import service.api.app, service.jobs.tasks; "
        "print(sorted(m for m in ('torch', 'stable_baselines3', 'pybullet') if m in sys.modules))"
    )
    assert _run_python(code) == "[]"


def test_start_up_freezes_its_objects_and_hands_the_lock_on_sooner(tmp_path: Path) -> None:
    code = (
        "import gc, sys, tempfile; from fastapi.testclient import TestClient; "
        "from service.api.app import create_app, GIL_SWITCH_SECONDS; "
        "from service.settings import Settings; "
        "s = Settings(data_dir=tempfile.mkdtemp()); "
        "before = gc.get_freeze_count(); "
        "client = TestClient(create_app(s, enqueue=lambda m: None)); client.__enter__(); "
        "print(before == 0, gc.get_freeze_count() > 10_000, "
        "sys.getswitchinterval() == GIL_SWITCH_SECONDS); client.__exit__(None, None, None)"
    )
    assert _run_python(code) == "True True True"


def _most_inside_at_once(gate: SubmissionGate, submissions: int) -> int:
    """The most of ``submissions`` concurrent ones that held a slot of ``gate`` at once."""
    inside = 0
    most = 0

    async def submit() -> None:
        nonlocal inside, most
        async with gate.slot():
            inside += 1
            most = max(most, inside)
            await asyncio.sleep(0.01)
            inside -= 1

    async def burst() -> None:
        await asyncio.gather(*(submit() for _ in range(submissions)))

    asyncio.run(burst())
    return most


def test_submissions_are_validated_one_at_a_time_by_default(tmp_path: Path) -> None:
    slots = settings_for(tmp_path, "sqlite://").submission_concurrency
    assert slots == 1
    gate = SubmissionGate(slots)
    assert _most_inside_at_once(gate, 10) == 1
    assert _most_inside_at_once(gate, 10) == 1  # a second event loop gets its own semaphore


def test_the_gate_lets_as_many_in_as_it_has_slots() -> None:
    assert _most_inside_at_once(SubmissionGate(slots=3), 10) == 3


def test_a_submission_waits_for_its_slot_before_it_takes_a_database_connection(
    sqlite_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Submissions queued at the gate must leave the connection pool to the reads.
    import threading

    from sqlalchemy import event

    from service.api.health import PROBE_THREAD

    upgrade(sqlite_url)
    database = Database(sqlite_url)
    app = create_app(settings_for(tmp_path, sqlite_url), RecordingEnqueue(database))
    engine = app.state.services.database.engine
    seen: list[str] = []
    slot = SubmissionGate.slot

    @asynccontextmanager
    async def recorded(gate: SubmissionGate) -> AsyncIterator[None]:
        seen.append("slot")
        async with slot(gate):
            yield

    def checkout(*_: Any) -> None:
        if threading.current_thread().name != PROBE_THREAD:
            seen.append("connection")

    monkeypatch.setattr(SubmissionGate, "slot", recorded)
    event.listen(engine, "checkout", checkout)
    try:
        with TestClient(app) as http:
            seen.clear()
            assert http.post("/missions", json=tiny()).status_code == 201
    finally:
        event.remove(engine, "checkout", checkout)
    assert seen[:2] == ["slot", "connection"], seen


def test_every_response_says_how_long_the_api_took(sqlite_url: str, tmp_path: Path) -> None:
    upgrade(sqlite_url)
    database = Database(sqlite_url)
    settings = settings_for(tmp_path, sqlite_url)
    with TestClient(create_app(settings, RecordingEnqueue(database))) as http:
        created = http.post("/missions", json=tiny())
        read = http.get(f"/missions/{created.json()['id']}")
        missing = http.get("/missions/nope")
    for response in (created, read, missing):
        name, _, duration = response.headers["server-timing"].partition(";dur=")
        assert name == "app" and float(duration) >= 0, response.headers["server-timing"]
    assert missing.status_code == 404


@pytest.mark.skipif(not hasattr(os, "nice"), reason="os.nice is Unix only")
def test_a_worker_lowers_its_own_priority() -> None:
    code = (
        "import os; from service.jobs.priority import lower_priority; "
        "before = os.nice(0); lower_priority(3); print(os.nice(0) - before)"
    )
    expected = str(min(3, 19 - os.nice(0)))
    assert _run_python(code) == expected


def _run_in_session(code: str, own_session: bool) -> str:
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        start_new_session=own_session,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


AUTOGROUP_CODE = (
    "from service.jobs.priority import autogroup_nice, lower_priority; "
    "before = autogroup_nice(); lower_priority(3); print(before, autogroup_nice())"
)


@pytest.mark.skipif(autogroup_nice() is None, reason="no Linux autogroup scheduling here")
def test_a_worker_in_a_session_of_its_own_lowers_its_sessions_share_of_the_cpu() -> None:
    # With autogroup scheduling the sessions share the CPU first: a worker's niceness alone
    # leaves its session an equal share with the API's.
    before, after = map(int, _run_in_session(AUTOGROUP_CODE, own_session=True).split())
    assert after == min(19, before + 3)


@pytest.mark.skipif(autogroup_nice() is None, reason="no Linux autogroup scheduling here")
def test_a_worker_sharing_a_session_leaves_the_sessions_group_alone() -> None:
    # The group is the shell's (here the test's): lowering it would lower them too.
    ours = autogroup_nice()
    before, after = map(int, _run_in_session(AUTOGROUP_CODE, own_session=False).split())
    assert before == after == ours == autogroup_nice()


def _keyed_app(sqlite_url: str, tmp_path: Path) -> tuple[Database, FastAPI]:
    """A migrated SQLite database and the API on it with the keys alpha and beta."""
    upgrade(sqlite_url)
    database = Database(sqlite_url)
    settings = settings_for(tmp_path, sqlite_url, keys=["alpha", "beta"])
    return database, create_app(settings, RecordingEnqueue(database))


def test_reading_a_mission_takes_one_hop_to_the_thread_pool(
    sqlite_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Pollers read missions: each hop between the event loop and the thread pool waits for
    # the interpreter lock again, so the read does its session, query and view in one.
    import anyio.to_thread

    from service.api.views import mission_view
    from service.repository import get_mission

    database, app = _keyed_app(sqlite_url, tmp_path)
    hops: list[str] = []
    run_sync = anyio.to_thread.run_sync

    async def counted(function, *args, **kwargs):  # type: ignore[no-untyped-def]
        hops.append(getattr(function, "__name__", repr(function)))
        return await run_sync(function, *args, **kwargs)

    with TestClient(app) as http:
        alpha = {"Authorization": "Bearer alpha"}
        mission_id = http.post("/missions", json=tiny(), headers=alpha).json()["id"]
        monkeypatch.setattr(anyio.to_thread, "run_sync", counted)
        read = http.get(f"/missions/{mission_id}", headers=alpha)
        read_hops = list(hops)
        other_key = http.get(f"/missions/{mission_id}", headers={"Authorization": "Bearer beta"})
        malformed = http.get("/missions/not-an-id", headers=alpha)
    assert len(read_hops) == 1, read_hops
    assert read.status_code == 200 and read.headers["content-type"] == "application/json"
    with database.session() as session:
        found = get_mission(session, mission_id)
        assert found is not None
        expected = mission_view(found).model_dump(mode="json", by_alias=True)
    assert read.json() == expected and read.json()["links"]["self"] == f"/missions/{mission_id}"
    assert other_key.status_code == 404 and malformed.status_code == 404
    assert other_key.json()["detail"] == f"no mission {mission_id!r}"


def test_the_polled_read_is_served_before_the_router_and_every_other_case_by_it(
    sqlite_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from service.api import fast_read, missions

    database, app = _keyed_app(sqlite_url, tmp_path)
    served: list[str] = []

    def spy(where: str, read: Callable[..., bytes], fail: bool = False) -> Callable[..., bytes]:
        def call(*args: Any) -> bytes:
            served.append(where)
            if fail and served.count(where) == 1:
                raise OSError("the database went away")
            return read(*args)

        return call

    with TestClient(app) as http:
        alpha, beta = {"Authorization": "Bearer alpha"}, {"Authorization": "Bearer beta"}
        mission_id = http.post("/missions", json=tiny(), headers=alpha).json()["id"]
        monkeypatch.setattr(fast_read, "mission_json", spy("fast", missions.mission_json))
        monkeypatch.setattr(missions, "mission_json", spy("route", missions.mission_json))
        read = http.get(f"/missions/{mission_id.upper()}", headers=alpha)
        assert (read.status_code, served) == (200, ["fast"])
        assert read.headers["server-timing"].startswith("app;dur=")
        assert read.content == missions.mission_json(database, mission_id, "alpha")
        served.clear()
        assert http.get(f"/missions/{mission_id}", headers=beta).status_code == 404
        assert served == ["fast", "route"]  # another key's mission: the route answers
        served.clear()
        for headers in ({}, {"Authorization": "Bearer gamma"}, {"Authorization": "Basic alpha"}):
            assert http.get(f"/missions/{mission_id}", headers=headers).status_code == 401
        assert http.get("/missions/not-an-id", headers=alpha).status_code == 404
        assert served == ["route"]  # only the malformed id reached a read, the route's
        served.clear()
        monkeypatch.setattr(fast_read, "mission_json", spy("fast", missions.mission_json, True))
        again = http.get(f"/missions/{mission_id}", headers=alpha)
        assert (again.status_code, served) == (200, ["fast", "route"])  # a failure: the app
