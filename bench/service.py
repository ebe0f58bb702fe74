"""Service benchmark: API latency under load, time to the first training step, worker scaling.

Run with ``.venv/bin/python bench/service.py`` (embedded SQLite + SQLAlchemy broker) or with
``--redis redis://127.0.0.1:6379/N --postgres postgresql://postgres@127.0.0.1:5432`` (Redis
databases N and N+1 are emptied before each phase; each phase creates and drops its own
PostgreSQL database on that server). Starts its own ``ltlnav serve`` / ``ltlnav worker``
processes on free ports with their data under a temporary directory, and prints one table.

It is one script past 400 lines on purpose: its three phases share the process harness (start,
wait, stop) and print one table.

1. ``POST /missions`` latency (sequential submissions, API without a worker: missions queue).
2. ``GET /missions/{id}`` latency with ``--pollers`` concurrent clients (httpx, asyncio), each
   reading every ``--interval`` seconds (1 s: ``ltlnav submit --wait`` and the dashboard poll
   about that often), then back to back (no pause: the server's capacity).
3. Per worker count K: a 4-sub-task mission with a fixed budget per sub-task on one worker with
   ``--concurrency K``: time from submission to the first training step (first ``steps_done``
   > 0 seen by polling every 50 ms; progress is written every ``heartbeat`` seconds) and the
   wall time to ``done``. Speed-up = wall(1) / wall(K); ideal = K while K <= sub-tasks. One
   warm-up submission (cancelled at once) goes first: the cold first POST is reported in 1.

``--load`` runs the load mode instead (``bench/service_load.py``: hundreds of tiny missions
from 10 API keys on 2 workers under 50 pollers, then the accounting; ``--load --help``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402

LTLNAV = Path(sys.executable).with_name("ltlnav")
EXAMPLE = "bench-gf2"
HEARTBEAT = 0.5


def bench_mission(timesteps: int) -> dict[str, Any]:
    """GF a && GF b in a 4 x 4 m world: a prefix and a suffix of two sub-tasks each (four)."""
    return {
        "name": EXAMPLE,
        "task": "[]!obstacle && []<>a && []<>b",
        "robot": {"model": "point", "start": [0.5, 0.5], "radius": 0.05},
        "planner": {"seed": 1, "refine_iterations": 300},
        "world": {
            "bounds": [[0, 4], [0, 4]],
            "obstacles": [{"box": {"min": [2.6, 2.6], "max": [3.4, 3.4]}}],
            "regions": {
                "a": {"ball": {"center": [3.4, 0.6], "radius": 0.3}},
                "b": {"box": {"min": [0.2, 3.2], "max": [0.8, 3.8]}},
            },
        },
        "training": {
            "n_timesteps": timesteps,
            "eval_freq": max(timesteps // 4, 1),
            "eval_episodes": 5,
            "final_eval_episodes": 10,
            "mission_episodes": 10,
            "hyperparams": {"policy_kwargs": {"net_arch": [32, 32]}},
        },
    }


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@dataclass
class Layout:
    """Where one run keeps its data, and how its processes reach each other."""

    root: Path
    redis: str | None
    postgres: str | None
    extra: dict[str, str] = field(default_factory=dict)
    """More ``LTLNAV_...`` settings of its processes (the load mode's keys and quotas)."""

    def env(self) -> dict[str, str]:
        env = {
            k: v
            for k, v in os.environ.items()
            if not k.startswith("LTLNAV_") and k != "DATABASE_URL"
        }
        env.update(
            LTLNAV_DATA_DIR=str(self.root / "data"),
            LTLNAV_EXAMPLES_DIR=str(self.root / "examples"),
            LTLNAV_HEARTBEAT_SECONDS=str(HEARTBEAT),
            # The bench submits hundreds of missions at once: no per-key quotas (0: none).
            LTLNAV_QUOTA_ACTIVE_MISSIONS="0",
            LTLNAV_QUOTA_SUBMISSIONS_PER_MINUTE="0",
        )
        if self.redis:
            base, _, db = self.redis.rpartition("/")
            results = f"{base}/{int(db) + 1}" if db.isdigit() else self.redis
            env.update(LTLNAV_BROKER_URL=self.redis, LTLNAV_RESULT_BACKEND=results)
        if self.postgres:
            env["DATABASE_URL"] = self.postgres
        env.update(self.extra)
        return env


def stop_on_sigterm() -> None:
    """Let SIGTERM end a bench as Ctrl-C does: the ``KeyboardInterrupt`` unwinds every
    ``process`` context, which stops its servers and workers, and removes the temporary data."""

    def raise_interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, raise_interrupt)


_interrupted: set[int] = set()
"""Processes ``interrupt`` already sent SIGINT (``process`` then only waits for them)."""


def interrupt(procs: list[subprocess.Popen[bytes]]) -> None:
    """SIGINT to every one of ``procs`` still running, at once: they shut down in parallel
    rather than one after the other when their ``process`` contexts end."""
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            _interrupted.add(proc.pid)


@contextmanager
def process(
    command: list[str], env: dict[str, str], log: Path
) -> Iterator[subprocess.Popen[bytes]]:
    """Run ``command`` (its output to ``log``) in a session of its own; at the end SIGINT (once),
    SIGKILL after 30 s, and SIGKILL of whatever of its group is left (pool children)."""
    with log.open("w") as out:
        proc = subprocess.Popen(
            command, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
    try:
        yield proc
    finally:
        if proc.poll() is None and proc.pid not in _interrupted:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        _interrupted.discard(proc.pid)
        with suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@contextmanager
def api_server(
    layout: Layout, started: list[subprocess.Popen[bytes]] | None = None
) -> Iterator[str]:
    """``ltlnav serve --no-worker`` on a free port; yields its URL once /healthz answers. Its
    process is appended to ``started`` when given (the load mode reads its CPU time)."""
    port = free_port()
    log = layout.root / f"serve-{port}.log"
    command = [str(LTLNAV), "serve", "--no-worker", "--host", "127.0.0.1", "--port", str(port)]
    with process(command, layout.env(), log) as proc:
        if started is not None:
            started.append(proc)
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 90
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"ltlnav serve exited:\n{log.read_text()[-3000:]}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"ltlnav serve: no /healthz in 90 s:\n{log.read_text()[-3000:]}")
            try:
                if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        yield url


@contextmanager
def start_worker(
    layout: Layout, concurrency: int, name: str | None = None, nice: int = 0
) -> Iterator[tuple[subprocess.Popen[bytes], Path]]:
    """``ltlnav worker --concurrency K`` started (not yet ready: see ``wait_ready``); yields
    the process and its log. ``name`` tells the logs of several workers of a layout apart;
    ``nice`` > 0 runs it under ``nice -n`` (training yields the CPU to the API)."""
    log = layout.root / f"worker-{name or concurrency}.log"
    command = [str(LTLNAV), "worker", "--concurrency", str(concurrency)]
    if nice:
        command = ["nice", "-n", str(nice), *command]
    with process(command, layout.env(), log) as proc:
        yield proc, log


def wait_ready(proc: subprocess.Popen[bytes], log: Path) -> None:
    """Return once the worker's log says Celery is ready (error after 120 s or on exit)."""
    deadline = time.monotonic() + 120
    while " ready." not in log.read_text():
        if proc.poll() is not None:
            raise RuntimeError(f"ltlnav worker exited:\n{log.read_text()[-3000:]}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"worker not ready in 120 s:\n{log.read_text()[-3000:]}")
        time.sleep(0.2)


@contextmanager
def worker(layout: Layout, concurrency: int) -> Iterator[None]:
    """``ltlnav worker --concurrency K``; returns once Celery says it is ready."""
    with start_worker(layout, concurrency) as (proc, log):
        wait_ready(proc, log)
        yield


@contextmanager
def phase_layout(parent: Path, name: str, args: argparse.Namespace) -> Iterator[Layout]:
    """A fresh state for one phase: a data directory, and with the server options a new
    PostgreSQL database (dropped afterwards) and emptied Redis databases."""
    root = parent / name
    (root / "examples").mkdir(parents=True)
    mission = bench_mission(args.timesteps)
    (root / "examples" / f"{EXAMPLE}.json").write_text(json.dumps(mission))
    database = None
    if args.postgres:
        from sqlalchemy import create_engine, text

        from service.settings import normalise_database_url

        server = normalise_database_url(args.postgres.rstrip("/"))
        database = f"ltlnav_bench_{name.replace('-', '_')}_{os.getpid()}"
        admin = create_engine(f"{server}/postgres", isolation_level="AUTOCOMMIT")
        with admin.connect() as connection:
            connection.execute(text(f'CREATE DATABASE "{database}"'))
        database = f"{server}/{database}"
    if args.redis:
        import redis

        layout_env = Layout(root, args.redis, None).env()
        for url in (layout_env["LTLNAV_BROKER_URL"], layout_env["LTLNAV_RESULT_BACKEND"]):
            redis.Redis.from_url(url).flushdb()
    try:
        yield Layout(root, args.redis, database)
    finally:
        if database is not None:
            name_only = database.rsplit("/", 1)[1]
            with admin.connect() as connection:
                connection.execute(text(f'DROP DATABASE IF EXISTS "{name_only}" WITH (FORCE)'))
            admin.dispose()


def percentiles(samples: list[float]) -> tuple[float, float, float]:
    """p50, p99 and max in milliseconds."""
    ordered = sorted(samples)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return 1000 * statistics.median(ordered), 1000 * p99, 1000 * ordered[-1]


def submit_latency(url: str, count: int) -> tuple[float, list[float], list[str]]:
    """The first (cold) POST's time, then ``count`` more, and the missions' ids."""
    times, ids = [], []
    with httpx.Client(base_url=url, timeout=30) as client:
        start = time.perf_counter()
        client.post("/missions", json={"example": EXAMPLE}).raise_for_status()
        cold = time.perf_counter() - start
        for _ in range(count):
            start = time.perf_counter()
            response = client.post("/missions", json={"example": EXAMPLE})
            times.append(time.perf_counter() - start)
            response.raise_for_status()
            ids.append(response.json()["id"])
    return cold, times, ids


def read_latency(url: str, ids: list[str], count: int) -> list[float]:
    """``count`` sequential GETs from one client: the cost of a read without queueing."""
    times = []
    with httpx.Client(base_url=url, timeout=30) as client:
        for i in range(count):
            start = time.perf_counter()
            client.get(f"/missions/{ids[i % len(ids)]}").raise_for_status()
            times.append(time.perf_counter() - start)
    return times


async def poll_latency(
    url: str, ids: list[str], pollers: int, seconds: float, interval: float
) -> list[float]:
    """``pollers`` clients each reading a random mission every ``interval`` seconds (0: back
    to back, the server's capacity), for ``seconds``; the latencies."""
    times: list[float] = []
    limits = httpx.Limits(max_connections=pollers, max_keepalive_connections=pollers)
    async with httpx.AsyncClient(base_url=url, timeout=30, limits=limits) as client:
        stop = time.monotonic() + seconds

        async def poller(seed: int) -> None:
            rng = random.Random(seed)
            await asyncio.sleep(rng.uniform(0, interval))
            while time.monotonic() < stop:
                start = time.perf_counter()
                response = await client.get(f"/missions/{rng.choice(ids)}")
                elapsed = time.perf_counter() - start
                times.append(elapsed)
                response.raise_for_status()
                await asyncio.sleep(max(0.0, interval - elapsed))

        await asyncio.gather(*(poller(i) for i in range(pollers)))
    return times


@dataclass
class MissionRun:
    concurrency: int
    first_step: float | None
    wall: float
    status: str
    subtasks: int
    phases: dict[str, float]
    """Seconds from submission to the first poll that saw each status."""
    training_seconds: list[float]
    """Each sub-task job's started -> finished time, from the database."""


def job_seconds(layout: Layout, mission_id: str) -> list[float]:
    """started_at -> finished_at of the mission's jobs, read from the service database."""
    from sqlalchemy import select

    from service.db import Database
    from service.models import Job
    from service.settings import Settings

    url = layout.postgres or Settings(data_dir=layout.root / "data").database_url
    database = Database(url)
    try:
        with database.session() as session:
            jobs = session.scalars(select(Job).where(Job.mission_id == mission_id)).all()
            return [
                (job.finished_at - job.started_at).total_seconds()
                for job in jobs
                if job.started_at is not None and job.finished_at is not None
            ]
    finally:
        database.dispose()


def run_mission(url: str, layout: Layout, concurrency: int, limit: float) -> MissionRun:
    with httpx.Client(base_url=url, timeout=30) as client:
        # Warm-up: the API's first submission imports the task modules (see the cold POST).
        warm = client.post("/missions", json={"example": EXAMPLE}).json()["id"]
        client.post(f"/missions/{warm}/cancel").raise_for_status()
        start = time.perf_counter()
        response = client.post("/missions", json={"example": EXAMPLE})
        response.raise_for_status()
        mission_id = response.json()["id"]
        first_step: float | None = None
        phases: dict[str, float] = {}
        while True:
            mission = client.get(f"/missions/{mission_id}").json()
            now = time.perf_counter() - start
            phases.setdefault(mission["status"], now)
            if first_step is None and any(j["steps_done"] > 0 for j in mission["jobs"]):
                first_step = now
            if mission["status"] in ("done", "failed", "cancelled") or now > limit:
                break
            time.sleep(0.05)
    return MissionRun(
        concurrency,
        first_step,
        now,
        mission["status"],
        len(mission["jobs"]),
        phases,
        job_seconds(layout, mission_id),
    )


def mission_rows(runs: list[MissionRun], timesteps: int) -> list[tuple[str, str, str]]:
    """Table rows of the mission runs: first step per run, then wall time and speed-up."""
    rows = []
    for run in runs:
        first = "-" if run.first_step is None else f"{run.first_step:.2f} s"
        verdict = "met" if run.first_step is not None and run.first_step < 3 else "MISSED"
        rows.append(
            (
                f"first training step, worker --concurrency {run.concurrency}",
                first,
                f"< 3 s: {verdict} (progress every {HEARTBEAT} s)",
            )
        )
    for run in runs:
        phases = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in run.phases.items())
        trained = run.training_seconds
        span = run.phases.get("evaluating", run.wall) - run.phases.get("training", 0.0)
        rows.append(
            (
                f"  concurrency {run.concurrency}: status first seen at",
                phases,
                f"jobs {' + '.join(f'{s:.1f}' for s in trained)} = {sum(trained):.1f} s; "
                f"{sum(trained) / max(span, 1e-9):.2f} running on average",
            )
        )
    for run in runs:
        speedup = runs[0].wall / run.wall
        ideal = run.concurrency / runs[0].concurrency
        target = "-"
        if run is not runs[0]:
            verdict = "met" if speedup >= 0.9 * ideal else "MISSED"
            target = f">= {0.9 * ideal:.1f}x (ideal {ideal:.0f}x): {verdict}"
        rows.append(
            (
                f"{run.subtasks} sub-tasks x {timesteps} steps, concurrency {run.concurrency}",
                f"{run.status} in {run.wall:.1f} s, speed-up {speedup:.2f}x",
                target,
            )
        )
    return rows


def machine_note() -> str:
    load = os.getloadavg()
    return (
        f"machine: {os.cpu_count()} cores, load average {load[0]:.1f} / {load[1]:.1f} / "
        f"{load[2]:.1f} at start (other jobs running make every figure pessimistic)"
    )


def main() -> None:
    stop_on_sigterm()
    if "--load" in sys.argv[1:]:
        # The load mode lives in bench/service_load.py (its own options, see --load --help).
        from bench.service_load import main as load_main

        load_main([arg for arg in sys.argv[1:] if arg != "--load"])
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--submissions", type=int, default=200, help="POST /missions samples")
    parser.add_argument("--pollers", type=int, default=50, help="concurrent GET clients")
    parser.add_argument("--seconds", type=float, default=15.0, help="duration of the GET load")
    parser.add_argument(
        "--interval", type=float, default=1.0, help="seconds between a poller's reads"
    )
    parser.add_argument("--timesteps", type=int, default=3000, help="budget per sub-task")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="K to compare")
    parser.add_argument("--skip-scaling", action="store_true", help="latency only")
    parser.add_argument("--redis", help="Redis URL of the broker (.../N); results in db N+1")
    parser.add_argument("--postgres", help="PostgreSQL server URL (no database name)")
    parser.add_argument("--limit", type=float, default=900.0, help="give up on a mission after")
    args = parser.parse_args()

    print(machine_note(), flush=True)
    rows: list[tuple[str, str, str]] = []
    with tempfile.TemporaryDirectory(prefix="ltlnav-bench-") as tmp:
        parent = Path(tmp)
        with phase_layout(parent, "latency", args) as layout, api_server(layout) as url:
            cold, posts, ids = submit_latency(url, args.submissions)
            single = read_latency(url, ids, args.submissions)
            paced = asyncio.run(poll_latency(url, ids, args.pollers, args.seconds, args.interval))
            flat_out = asyncio.run(poll_latency(url, ids, args.pollers, args.seconds, 0.0))
        p50, p99, worst = percentiles(posts)
        rows.append(
            (
                f"POST /missions ({len(posts)} sequential, after one cold)",
                f"p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {worst:.1f} ms",
                f"first (cold) POST {1000 * cold:.0f} ms",
            )
        )
        p50, p99, worst = percentiles(single)
        rows.append(
            (
                f"GET /missions/{{id}} ({len(single)} sequential, one client)",
                f"p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {worst:.1f} ms",
                "-",
            )
        )
        for label, gets in (
            (f"every {args.interval:g} s", paced),
            ("back to back (capacity)", flat_out),
        ):
            p50, p99, worst = percentiles(gets)
            verdict = "met" if p99 < 50 else "MISSED"
            rows.append(
                (
                    f"GET /missions/{{id}}, {args.pollers} pollers {label}",
                    f"p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {worst:.1f} ms, "
                    f"{len(gets) / args.seconds:.0f} req/s",
                    f"p99 < 50 ms: {verdict}",
                )
            )
        print("latency done: " + " | ".join(row[1] for row in rows), flush=True)

        runs: list[MissionRun] = []
        for k in [] if args.skip_scaling else args.workers:
            with (
                phase_layout(parent, f"workers-{k}", args) as layout,
                api_server(layout) as url,
                worker(layout, k),
            ):
                runs.append(run_mission(url, layout, k, args.limit))
            run = runs[-1]
            print(
                f"K={k}: {run.status} in {run.wall:.1f} s, first step {run.first_step}", flush=True
            )
        rows.extend(mission_rows(runs, args.timesteps))

    storage = (
        "Redis + PostgreSQL" if args.redis or args.postgres else "embedded SQLite + sqla broker"
    )
    print(f"\nltlnav service benchmark ({storage})")
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    header = ("measure", "result", "target")
    widths = [max(w, len(h)) for w, h in zip(widths, header, strict=True)]
    for row in [header, tuple("-" * w for w in widths), *rows]:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)))


if __name__ == "__main__":
    main()
