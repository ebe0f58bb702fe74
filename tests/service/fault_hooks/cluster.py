"""The processes of one deployment under test: real workers (``fault_hooks.worker``), an API
process, the state database they share and what a fault left in it.

Two deployments: ``embedded`` (SQLite state, ``sqla+sqlite`` broker, ``db+sqlite`` results, all
under one folder) and ``redis-postgresql`` (a PostgreSQL database and a Redis database on
127.0.0.1, optionally reached by the workers through a ``PauseProxy``). Every process is
started in a session of its own and ``stop()`` SIGKILLs each process group it started.
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlsplit, urlunsplit

from sqlalchemy import create_engine, func, select, text

from service import repository
from service.db import Database, upgrade
from service.jobs.tasks import enqueue_mission
from service.models import Checkpoint, Evaluation, Event, Job, Mission
from service.settings import Settings
from tests.service.fault_hooks.proxy import PauseProxy
from tests.workers.missions import TINY, tiny_mission

REPO = Path(__file__).resolve().parents[3]

T = TypeVar("T")


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def with_port(url: str, port: int) -> str:
    """``url`` with its port replaced (host 127.0.0.1)."""
    parts = urlsplit(url)
    user = f"{parts.username}@" if parts.username else ""
    return urlunsplit(parts._replace(netloc=f"{user}127.0.0.1:{port}"))


def _die_with_parent() -> None:
    """In a started process: be SIGKILLed when the process that started it ends (Linux
    ``PR_SET_PDEATHSIG``), so that a test or bench that dies leaves no worker behind."""
    with suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)


def kill_group(process: subprocess.Popen[bytes]) -> None:
    """SIGKILL a process and everything in its process group (a worker's pool too)."""
    with suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    with suppress(subprocess.TimeoutExpired):
        process.wait(timeout=30)


@dataclass
class Snapshot:
    """A mission's rows at one moment."""

    mission: Mission
    jobs: list[Job]
    checkpoints: dict[int, list[Checkpoint]]
    """By job id, by steps."""
    curves: dict[int, list[Evaluation]]
    """By job id, by steps."""

    def job(self, index: int, repair_round: int = 0) -> Job:
        return next(j for j in self.jobs if j.index == index and j.repair_round == repair_round)

    def latest(self, job: Job) -> int:
        """The newest checkpoint's steps of ``job`` (0: none)."""
        saved = self.checkpoints.get(job.id) or []
        return saved[-1].steps if saved else 0


@dataclass
class Cluster:
    """One deployment's settings, environment and processes (see the module docstring)."""

    kind: str
    settings: Settings
    """As the test process sees them (direct database URL)."""
    env: dict[str, str]
    """The environment of every process it starts (a worker's database may be a proxy)."""
    logs: Path
    processes: list[subprocess.Popen[bytes]] = field(default_factory=list)
    proxies: list[PauseProxy] = field(default_factory=list)
    db_proxy: PauseProxy | None = None
    _db: Database | None = None

    @property
    def db(self) -> Database:
        if self._db is None:
            self._db = Database(self.settings.database_url)
        return self._db

    def _start(self, name: str, command: list[str], env: Mapping[str, str]) -> Any:
        log = (self.logs / f"{len(self.processes):02d}-{name}.log").open("wb")
        process = subprocess.Popen(
            command,
            cwd=REPO,
            env=dict(env),
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        log.close()
        self.processes.append(process)
        return process

    def start_worker(
        self, faults: Mapping[str, str] | None = None, concurrency: int = 2
    ) -> subprocess.Popen[bytes]:
        """A worker (``concurrency`` training processes) with the ``FAULT_*`` it is given."""
        command = [sys.executable, "-m", "tests.service.fault_hooks.worker", str(concurrency)]
        return self._start("worker", command, {**self.env, **(faults or {})})

    def start_api(self, port: int) -> subprocess.Popen[bytes]:
        """``ltlnav serve --no-worker`` on ``127.0.0.1:port`` (direct database URL)."""
        env = {**self.env, "LTLNAV_DATABASE_URL": self.settings.database_url}
        command = [sys.executable, "-m", "service.cli", "serve", "--no-worker", "--port", str(port)]
        return self._start("api", command, env)

    def document(
        self, name: str | None = None, task: str | None = None, **training: Any
    ) -> dict[str, Any]:
        """The tiny mission (``TINY``) with ``training`` overrides, named ``name``, with the
        formula ``task`` (None: the tiny one)."""
        document = tiny_mission(**training).model_dump(mode="json")
        document["name"] = name or TINY["name"]
        if task is not None:
            document["task"] = task
        return document

    def submit(
        self,
        name: str | None = None,
        broker_url: str | None = None,
        task: str | None = None,
        **training: Any,
    ) -> tuple[str, str | None]:
        """Store a queued mission and send its plan task as the API does (through
        ``broker_url`` if given); its id and the send error (None: sent)."""
        document = self.document(name, task, **training)
        with self.db.session() as session:
            mission_id = repository.create_mission(session, document["name"], document, None).id
        settings = self.settings
        if broker_url is not None:
            settings = settings.model_copy(update={"broker_url": broker_url})
        try:
            enqueue_mission(mission_id, settings)
        except Exception as error:  # the broker is down: the reconciler sends it
            return mission_id, f"{type(error).__name__}: {error}"
        return mission_id, None

    def snapshot(self, mission_id: str) -> Snapshot:
        """The mission's rows now."""
        with self.db.session() as session:
            mission = repository.get_mission(session, mission_id)
            assert mission is not None, mission_id
            jobs = repository.mission_jobs(session, mission_id)
            ids = [j.id for j in jobs]
            saved = session.scalars(
                select(Checkpoint).where(Checkpoint.job_id.in_(ids)).order_by(Checkpoint.steps)
            )
            points = session.scalars(
                select(Evaluation).where(Evaluation.job_id.in_(ids)).order_by(Evaluation.steps)
            )
            checkpoints: dict[int, list[Checkpoint]] = {i: [] for i in ids}
            curves: dict[int, list[Evaluation]] = {i: [] for i in ids}
            for row in saved:
                checkpoints[row.job_id].append(row)
            for point in points:
                assert point.job_id is not None
                curves[point.job_id].append(point)
            return Snapshot(mission, jobs, checkpoints, curves)

    def duplicates(self, mission_id: str) -> int:
        """Rows written twice for one mission: evaluation rows of a job at the same steps and
        checkpoint rows of a job at the same steps (each extra row counts one)."""
        extra = 0
        with self.db.session() as session:
            for model in (Evaluation, Checkpoint):
                counts = session.execute(
                    select(func.count())
                    .select_from(model)
                    .join(Job, Job.id == model.job_id)
                    .where(Job.mission_id == mission_id)
                    .group_by(model.job_id, model.steps)
                    .having(func.count() > 1)
                )
                extra += sum(int(n) - 1 for (n,) in counts)
        return extra

    def events(self, mission_id: str) -> list[tuple[str, dict[str, Any]]]:
        """The mission's events, oldest first, as ``(kind, payload)``."""
        with self.db.session() as session:
            rows = session.scalars(
                select(Event).where(Event.mission_id == mission_id).order_by(Event.id)
            )
            return [(row.kind, dict(row.payload)) for row in rows]

    def timed_events(self, mission_id: str) -> list[tuple[str, dict[str, Any], float]]:
        """As ``events``, each with its time (seconds since the epoch, host clock)."""
        with self.db.session() as session:
            rows = session.scalars(
                select(Event).where(Event.mission_id == mission_id).order_by(Event.id)
            )
            return [(row.kind, dict(row.payload), row.created_at.timestamp()) for row in rows]

    def wait(self, until: Callable[[], T | None], timeout: float, what: str) -> T:
        """Poll ``until()`` every 50 ms until it returns something (not None)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = until()
            if found is not None:
                return found
            time.sleep(0.05)
        raise AssertionError(f"{self.kind}: not {what} after {timeout:.0f} s\n{self.tail()}")

    def wait_final(self, mission_id: str, timeout: float) -> Snapshot:
        """The mission's rows once it has ended."""

        def final() -> Snapshot | None:
            found = self.snapshot(mission_id)
            return found if found.mission.status in repository.FINAL_STATES else None

        return self.wait(final, timeout, f"final ({mission_id})")

    def tail(self, chars: int = 2500) -> str:
        """The end of every process log (for assertion messages)."""
        return "\n".join(
            f"--- {p.name}\n{p.read_text(errors='replace')[-chars:]}"
            for p in sorted(self.logs.glob("*.log"))
        )

    def stop(self) -> None:
        """SIGKILL every process group started, stop the proxies."""
        for process in self.processes:
            kill_group(process)
        for proxy in self.proxies:
            proxy.stop()
        if self._db is not None:
            self._db.dispose()


FAST = {
    "LTLNAV_HEARTBEAT_SECONDS": "0.3",
    "LTLNAV_STALE_AFTER_SECONDS": "3",
    "LTLNAV_RECONCILE_SECONDS": "0.5",
    "LTLNAV_REQUEUE_AFTER_SECONDS": "3",
    "LTLNAV_MAX_ATTEMPTS": "3",
    "LTLNAV_RETRY_BACKOFF_SECONDS": "1",
}
"""Settings that bring a dead worker's work back within seconds (the test suite's)."""


def make_cluster(
    kind: str,
    root: Path,
    knobs: Mapping[str, str],
    database_url: str | None = None,
    redis_url: str | None = None,
    proxy_database: bool = False,
) -> Cluster:
    """A deployment under ``root`` (``embedded``, or ``redis-postgresql`` on ``database_url``,
    migrated, and ``redis_url``, flushed); with ``proxy_database`` the workers reach
    PostgreSQL through a ``PauseProxy`` (``cluster.db_proxy``)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("LTLNAV_", "FAULT_"))}
    env.pop("DATABASE_URL", None)
    env.update(knobs, LTLNAV_DATA_DIR=str(root / "var"), PYTHONPATH=str(REPO))
    proxy = None
    if kind == "redis-postgresql":
        assert database_url is not None and redis_url is not None
        env.update(
            LTLNAV_DATABASE_URL=database_url,
            LTLNAV_BROKER_URL=redis_url,
            LTLNAV_RESULT_BACKEND=redis_url,
        )
    values: dict[str, Any] = {
        k.removeprefix("LTLNAV_").lower(): v for k, v in env.items() if k.startswith("LTLNAV_")
    }
    settings = Settings(**values)
    if proxy_database and database_url is not None:
        proxy = PauseProxy(urlsplit(database_url).port or 5432).start()
        env["LTLNAV_DATABASE_URL"] = with_port(database_url, proxy.port)
    if kind == "embedded":
        upgrade(settings.database_url)
    logs = root / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    cluster = Cluster(kind, settings, env, logs, db_proxy=proxy)
    if proxy is not None:
        cluster.proxies.append(proxy)
    return cluster


@contextmanager
def small_filesystem(folder: Path, megabytes: int) -> Iterator[str]:
    """A tmpfs of ``megabytes`` mounted on ``folder`` (made) for the block, unmounted after.
    Yields why it could not be mounted ("" when it is: mounting needs root, or
    ``CAP_SYS_ADMIN``)."""
    folder.mkdir(parents=True, exist_ok=True)
    command = ["mount", "-t", "tmpfs", "-o", f"size={megabytes}m", "tmpfs", str(folder)]
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        yield f"{' '.join(command)}: {error}"
        return
    if run.returncode != 0:
        yield f"a small filesystem cannot be mounted here ({' '.join(command)}: " + (
            f"{run.stderr.strip() or run.returncode})"
        )
        return
    try:
        yield ""
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True, timeout=30, check=False)


PG_SERVER = "postgresql+psycopg://postgres@127.0.0.1:5432"


def _redis_ping(url: str) -> bool:
    import redis

    try:
        return bool(redis.Redis.from_url(url, socket_connect_timeout=1).ping())
    except redis.RedisError:
        return False


def ensure_redis(url: str) -> str:
    """Start the local Redis on 127.0.0.1:6379 when it is not running (as the CI does); why it
    cannot be used ("" when it answers)."""
    if _redis_ping(url):
        return ""
    logs = Path("/var/log/redis")
    command = [
        "redis-server", "--daemonize", "yes", "--bind", "127.0.0.1", "-::1",
        "--port", "6379", "--save", "", "--appendonly", "no",
        "--dir", "/var/lib/redis", "--logfile", str(logs / "ci.log"),
    ]  # fmt: skip
    try:
        logs.mkdir(parents=True, exist_ok=True)
        Path("/var/lib/redis").mkdir(parents=True, exist_ok=True)
        subprocess.run(command, check=False, capture_output=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as error:
        return f"Redis is not running on 127.0.0.1:6379 and did not start: {error}"
    for _ in range(50):
        if _redis_ping(url):
            return ""
        time.sleep(0.1)
    return "Redis is not running on 127.0.0.1:6379 and did not start"


def server_owns(folder: Path) -> str:
    """Give ``folder`` to the user the local PostgreSQL server runs as (its data directory's
    owner), so that it can hold a tablespace; why it cannot ("" when done)."""
    admin = create_engine(f"{PG_SERVER}/postgres")
    try:
        with admin.connect() as connection:
            data = Path(connection.execute(text("SHOW data_directory")).scalar_one())
        owner = data.stat()
        os.chown(folder, owner.st_uid, owner.st_gid)
    except OSError as error:
        return f"the PostgreSQL server's files are not this machine's to give ({error})"
    finally:
        admin.dispose()
    return ""


@contextmanager
def postgres_database(
    prefix: str = "ltlnav_faults", tablespace: Path | None = None
) -> Iterator[str]:
    """A fresh, migrated PostgreSQL database on 127.0.0.1:5432 (dropped afterwards); with
    ``tablespace`` (an empty folder the server owns: :func:`server_owns`) its files live there,
    in a tablespace of its own (dropped too)."""
    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    admin = create_engine(f"{PG_SERVER}/postgres", isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as connection:
            if tablespace is None:
                connection.execute(text(f'CREATE DATABASE "{name}"'))
            else:
                connection.execute(text(f"CREATE TABLESPACE \"{name}\" LOCATION '{tablespace}'"))
                connection.execute(text(f'CREATE DATABASE "{name}" TABLESPACE "{name}"'))
        url = f"{PG_SERVER}/{name}"
        upgrade(url)
        yield url
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
            if tablespace is not None:
                connection.execute(text(f'DROP TABLESPACE IF EXISTS "{name}"'))
        admin.dispose()
