"""End to end with a real ``celery worker`` process (``run_worker``) on both deployments: the
embedded defaults (SQLite state, ``sqla+sqlite`` broker, ``db+sqlite`` results, all under
``tmp_path``) and local Redis + PostgreSQL (started when absent). A tiny mission reaches
``done`` with a bundle; a worker whose whole process group is SIGKILLed mid-training is
replaced and the mission still completes, the killed jobs resuming from their checkpoints."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import text

from service import repository
from service.db import Database, upgrade
from service.jobs.tasks import enqueue_mission
from service.models import Base, JobStatus, MissionStatus
from service.settings import Settings
from tests.workers.missions import tiny_mission

REPO = Path(__file__).resolve().parents[2]
REDIS_DB = 13
"""The Redis database the tests use (flushed before and after)."""
REDIS_URL = f"redis://127.0.0.1:6379/{REDIS_DB}"

pytestmark = pytest.mark.timeout(240)

FAST = {
    "LTLNAV_HEARTBEAT_SECONDS": "0.3",
    "LTLNAV_STALE_AFTER_SECONDS": "3",
    "LTLNAV_RECONCILE_SECONDS": "0.5",
    "LTLNAV_REQUEUE_AFTER_SECONDS": "3",
}
"""Settings that make a dead worker's jobs come back within seconds."""


def _redis_ping() -> bool:
    import redis

    try:
        return bool(redis.Redis.from_url(REDIS_URL, socket_connect_timeout=1).ping())
    except redis.RedisError:
        return False


@pytest.fixture(scope="session")
def redis_url() -> str:
    """The local Redis (started as the CI does when it is not running), test db flushed."""
    if not _redis_ping():
        logs = Path("/var/log/redis")
        logs.mkdir(parents=True, exist_ok=True)
        Path("/var/lib/redis").mkdir(parents=True, exist_ok=True)
        command = [
            "redis-server", "--daemonize", "yes", "--bind", "127.0.0.1", "-::1",
            "--port", "6379", "--save", "", "--appendonly", "no",
            "--dir", "/var/lib/redis", "--logfile", str(logs / "ci.log"),
        ]  # fmt: skip
        try:
            subprocess.run(command, check=False, capture_output=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired) as error:
            pytest.skip(f"Redis is not running on 127.0.0.1:6379 and did not start: {error}")
        for _ in range(50):
            if _redis_ping():
                break
            time.sleep(0.1)
        else:
            pytest.skip("Redis is not running on 127.0.0.1:6379 and did not start")
    return REDIS_URL


def _flush_redis() -> None:
    import redis

    redis.Redis.from_url(REDIS_URL).flushdb()


@dataclass
class Service:
    """The settings a test's workers and its client share, and the worker processes."""

    settings: Settings
    env: dict[str, str]
    logs: Path
    workers: list[subprocess.Popen[bytes]]

    @property
    def db(self) -> Database:
        return Database(self.settings.database_url)

    def start_worker(self) -> subprocess.Popen[bytes]:
        log = (self.logs / f"worker-{len(self.workers)}.log").open("wb")
        code = "from service.jobs.celery_app import run_worker; run_worker(concurrency=2)"
        process = subprocess.Popen(
            [sys.executable, "-c", code],
            cwd=REPO,
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.workers.append(process)
        return process

    def submit(self, **training: Any) -> str:
        document = tiny_mission(**training).model_dump(mode="json")
        with self.db.session() as session:
            mission_id = repository.create_mission(session, document["name"], document, None).id
        enqueue_mission(mission_id, self.settings)
        return mission_id

    def mission(self, mission_id: str) -> Any:
        with self.db.session() as session:
            mission = repository.get_mission(session, mission_id)
            assert mission is not None
            jobs = repository.mission_jobs(session, mission_id, repair_round=0)
            saved = {job.index: repository.latest_checkpoint(session, job.id) for job in jobs}
            curves = {job.index: repository.learning_curve(session, job.id) for job in jobs}
            return mission, jobs, saved, curves

    def wait_final(self, mission_id: str, timeout: float) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = self.mission(mission_id)
            if found[0].status in repository.FINAL_STATES:
                return found
            time.sleep(0.25)
        raise AssertionError(f"mission still {found[0].status} after {timeout} s:\n{self.tail()}")

    def tail(self) -> str:
        return "\n".join(p.read_text()[-3000:] for p in sorted(self.logs.glob("worker-*.log")))


def kill_group(process: subprocess.Popen[bytes]) -> None:
    """SIGKILL a worker's main process and its pool (its whole process group)."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        return
    process.wait(timeout=30)


@pytest.fixture(params=["embedded", "redis-postgresql"])
def service(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Service]:
    """Settings (as the workers' environment too) for one deployment, workers stopped after."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("LTLNAV_")}
    env.pop("DATABASE_URL", None)
    env.update(FAST, LTLNAV_DATA_DIR=str(tmp_path / "var"), PYTHONPATH=str(REPO))
    if request.param == "redis-postgresql":
        database_url = request.getfixturevalue("migrated_postgres")
        request.getfixturevalue("redis_url")
        _flush_redis()
        env.update(
            LTLNAV_DATABASE_URL=database_url,
            LTLNAV_BROKER_URL=REDIS_URL,
            LTLNAV_RESULT_BACKEND=REDIS_URL,
        )
    fields: dict[str, Any] = {
        k.removeprefix("LTLNAV_").lower(): v for k, v in env.items() if k.startswith("LTLNAV_")
    }
    settings = Settings(**fields)
    if request.param == "embedded":
        upgrade(settings.database_url)
    logs = tmp_path / "logs"
    logs.mkdir()
    running = Service(settings, env, logs, [])
    try:
        yield running
    finally:
        for process in running.workers:
            kill_group(process)
        if request.param == "redis-postgresql":
            _flush_redis()
            tables = ", ".join(t.name for t in Base.metadata.sorted_tables)
            with running.db.engine.begin() as connection:
                connection.execute(text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))


@pytest.mark.slow
def test_a_tiny_mission_reaches_done_with_a_bundle(service: Service) -> None:
    service.start_worker()
    mission_id = service.submit()
    # well under a minute on an idle 2-core machine; the timeout allows for a loaded one
    mission, jobs, saved, curves = service.wait_final(mission_id, timeout=120)
    assert mission.status == MissionStatus.done, (mission.reason, service.tail())
    assert Path(mission.bundle_path).is_file() and mission.evaluation["episodes"] == 2
    assert mission.plan["subtasks"] and Path(mission.plan_image).is_file()
    assert len(jobs) == len(mission.plan["subtasks"])
    for job in jobs:
        assert job.status == JobStatus.done and job.attempts == 1
        assert job.result["final"] is not None and saved[job.index] is not None
        assert [point.steps for point in curves[job.index]] == [100, 200]
    with service.db.session() as session:  # hand-over repair rounds ran as jobs of their own
        repairs = [j for j in repository.mission_jobs(session, mission_id) if j.repair_round]
        assert {(j.repair_round, j.status) for j in repairs} <= {
            (r["round"], JobStatus.done) for r in mission.repairs or []
        }
        assert {j.repair_round for j in repairs} == {r["round"] for r in mission.repairs or []}


@pytest.mark.slow
def test_a_sigkilled_worker_is_replaced_and_jobs_resume_from_checkpoints(
    service: Service,
) -> None:
    first = service.start_worker()
    budget = 300
    mission_id = service.submit(n_timesteps=budget, eval_freq=100)
    deadline = time.monotonic() + 90
    while True:  # kill mid-training, once every running job has saved a checkpoint
        _, jobs, saved, _ = service.mission(mission_id)
        running = {job.index for job in jobs if job.status == JobStatus.running}
        at = {k: saved[k].steps for k in running if saved[k] is not None}
        if running and len(at) == len(running) and max(at.values()) < budget:
            break
        assert time.monotonic() < deadline, service.tail()
        time.sleep(0.05)
    kill_group(first)
    service.start_worker()
    mission, jobs, _, curves = service.wait_final(mission_id, timeout=120)
    assert mission.status == MissionStatus.done, (mission.reason, service.tail())
    assert Path(mission.bundle_path).is_file()
    for job in jobs:
        assert job.status == JobStatus.done and job.steps_done == budget
        steps = [point.steps for point in curves[job.index]]
        assert steps == sorted(set(steps)) and steps[-1] == budget
        if job.index in at:  # killed mid-training: resumed from its checkpoint, not from 0
            assert job.attempts >= 2 and job.result["resumed_from"] >= at[job.index]
        else:  # not started when the worker died: trained once
            assert job.attempts == 1 and job.result["resumed_from"] == 0


def test_broker_health_on_redis(redis_url: str, tmp_path: Path) -> None:
    from service.jobs.celery_app import broker_ok

    assert broker_ok(Settings(data_dir=tmp_path, broker_url=redis_url))
