"""Service load benchmark: many tiny missions from 10 API keys on 2 workers under 50 pollers.

Run with ``.venv/bin/python bench/service.py --load`` (or ``bench/service_load.py``): the
embedded defaults (SQLite + kombu's SQLAlchemy broker), and with ``--redis
redis://127.0.0.1:6379/N --postgres postgresql://postgres@127.0.0.1:5432`` Redis + PostgreSQL
as well, side by side in one table. Each backend gets a fresh state (``bench.service``'s
harness: ``ltlnav serve --no-worker`` on a free port, two ``ltlnav worker --concurrency 1``
processes, data under a temporary directory, its own PostgreSQL database, emptied Redis
databases), and every process is stopped at the end, also on errors and Ctrl-C.

1. ``--missions`` (500) tiny missions are submitted by 10 API keys (``LTLNAV_API_KEYS``; the
   per-key quotas are lifted with ``LTLNAV_QUOTA_ACTIVE_MISSIONS=0`` and
   ``LTLNAV_QUOTA_SUBMISSIONS_PER_MINUTE=0``). A tiny mission is one reach-avoid sub-task in a
   2 x 2 m world, 64 steps of SAC with an [8] net, one-episode evaluations, 40-step episodes
   and no hand-over repair; one in ten cannot be planned (a region enclosed by obstacles, or a
   planner allowed one iteration) and must end ``failed`` with its reason.
   The submitters run in a process of their own, which reports each new mission as it is
   created, so that their work is not done in the loop that times the pollers' reads.
2. Meanwhile ``--pollers`` (50) asyncio clients read ``GET /missions/{id}`` of random missions
   of their own key every ``--interval`` seconds: latency percentiles and every non-2xx.
3. Every ``--sample`` seconds the bench counts the broker's messages (embedded: the rows of
   ``kombu_message``; Redis: queued lists plus the unacked hash), the ``events`` rows and the
   missions by status. The service deletes consumed broker rows every
   ``LTLNAV_BROKER_CLEANUP_SECONDS`` (``--cleanup``, 5 s here) and, with
   ``LTLNAV_KEEP_FAILED_DAYS=0`` (set for the bench), the progress events of ended missions at
   the same pass: the tables must stay bounded. After the last mission ends it samples for
   two more clean-up periods and reports the final counts.
4. Accounting from the database: every mission ended (done, or failed with a non-empty
   reason; "lost" counts the others), no step ran twice (no two evaluation rows for one
   ``(job_id, steps)``, no two checkpoint rows for one ``(job_id, steps)``, no two whole-mission
   evaluations for one ``(mission_id, steps)``), and how many jobs, plannings and assemblies
   began more than once (1 each unless a fault).
"""

from __future__ import annotations

import argparse
import asyncio
import copy
import dataclasses
import json
import os
import random
import shlex
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
from sqlalchemy import create_engine, text  # noqa: E402
from sqlalchemy.engine import Engine  # noqa: E402

from bench.service import (  # noqa: E402
    api_server,
    interrupt,
    machine_note,
    phase_layout,
    start_worker,
    stop_on_sigterm,
    wait_ready,
)

KEYS = [f"bench-load-key-{i}" for i in range(10)]
"""The API keys the missions are spread over (mission i belongs to key i mod 10)."""

WORKERS = 2
"""Worker processes, each ``ltlnav worker --concurrency 1``."""

LAG_TICK = 0.01
"""Seconds the bench's loop-lag probe sleeps between its readings."""

FINAL = ("done", "failed", "cancelled")

KEEPALIVE_EXPIRY = 2.0
"""Seconds the bench's HTTP clients keep an idle connection (below uvicorn's 5 s)."""

TINY_LOAD: dict[str, Any] = {
    "name": "load-tiny",
    "task": "[]!obstacle && <>a",
    "robot": {"model": "point", "start": [0.5, 0.5], "radius": 0.05},
    "planner": {"seed": 1, "refine_iterations": 50},
    "world": {
        "bounds": [[0, 2], [0, 2]],
        "obstacles": [{"box": {"min": [0.9, 0.9], "max": [1.1, 1.1]}}],
        "regions": {"a": {"ball": {"center": [1.5, 0.5], "radius": 0.2}}},
    },
    "training": {
        "n_timesteps": 64,
        "eval_freq": 32,
        "eval_episodes": 1,
        "final_eval_episodes": 1,
        "mission_episodes": 1,
        "cycles": 1,
        "handover_rounds": 0,
        "env": {"max_steps": 40},
        "hyperparams": {
            "policy_kwargs": {"net_arch": [8]},
            "learning_starts": 16,
            "batch_size": 8,
            "buffer_size": 200,
        },
    },
}
"""One reach-avoid sub-task (reach a, avoid the obstacle): 64 steps, evaluations at 32 and 64
(a checkpoint each), one-episode evaluations of 40 steps at most, no hand-over repair."""

ENCLOSED_OBSTACLES = [
    {"box": {"min": [1.2, 1.2], "max": [1.9, 1.3]}},
    {"box": {"min": [1.2, 1.7], "max": [1.9, 1.8]}},
    {"box": {"min": [1.2, 1.2], "max": [1.3, 1.8]}},
    {"box": {"min": [1.8, 1.2], "max": [1.9, 1.8]}},
]
"""Four walls around region a of the infeasible mission (valid, but fails at planning)."""


def load_mission(index: int) -> tuple[str, dict[str, Any]]:
    """The kind and document of mission ``index``: ``tiny`` mostly; ``enclosed`` (index 3 mod
    20: region a walled in) and ``gives-up`` (4 mod 20: a second region and a planner allowed
    one iteration) pass validation and must fail at planning with a reason."""
    document = copy.deepcopy(TINY_LOAD)
    if index % 20 == 3:
        document["name"] = "load-enclosed"
        document["world"]["obstacles"] = copy.deepcopy(ENCLOSED_OBSTACLES)
        document["world"]["regions"]["a"] = {"ball": {"center": [1.55, 1.5], "radius": 0.1}}
        return "enclosed", document
    if index % 20 == 4:
        document["name"] = "load-gives-up"
        document["task"] = "[]!obstacle && <>a && <>b"
        document["world"]["regions"]["b"] = {"box": {"min": [0.2, 1.6], "max": [0.5, 1.9]}}
        document["planner"] = {"seed": 1, "max_iterations": 1}
        return "gives-up", document
    return "tiny", document


@dataclass
class Sample:
    """One reading of the tables every few seconds."""

    at: float
    broker: int | None
    events: int
    statuses: dict[str, int]


@dataclass
class LoadResult:
    """What one backend's run measured."""

    backend: str
    missions: int
    kinds: dict[str, str] = field(default_factory=dict)
    """Mission id -> kind (see ``load_mission``)."""
    statuses: dict[str, int] = field(default_factory=dict)
    lost: int = 0
    failed_without_reason: int = 0
    unexpected: list[str] = field(default_factory=list)
    """Missions that ended otherwise than their kind says (id, kind, status, reason)."""
    wall: float = 0.0
    """First submission to the last mission's end (database timestamps)."""
    submit_seconds: float = 0.0
    post_times: list[float] = field(default_factory=list)
    post_errors: Counter[str] = field(default_factory=Counter)
    get_times: list[float] = field(default_factory=list)
    get_server_times: list[float] = field(default_factory=list)
    """The API's own time for each GET (its ``Server-Timing`` header), seconds."""
    get_sent: list[float] = field(default_factory=list)
    """When each GET of ``get_times`` was sent, in seconds from the first submission."""
    get_errors: Counter[str] = field(default_factory=Counter)
    loop_lags: list[tuple[float, float]] = field(default_factory=list)
    """(when, lag): how late the bench's own event loop woke from a 10 ms sleep, seconds from
    the first submission (a late loop delays the replies it reads, and so every GET time)."""
    poll_seconds: float = 0.0
    api_cpu_seconds: float = 0.0
    """CPU time (user + system) of the API's processes from the first POST to the pollers'
    end."""
    api_processes: int = 1
    samples: list[Sample] = field(default_factory=list)
    duplicate_evaluations: int = 0
    duplicate_checkpoints: int = 0
    duplicate_mission_evaluations: int = 0
    progress_events_left: int = 0
    """Progress events of ended missions still there at the end (0: the pruning ran)."""
    retried_jobs: int = 0
    retried_plans: int = 0
    retried_assemblies: int = 0
    jobs: int = 0
    load_before: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_after: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def ended(self) -> int:
        return sum(self.statuses.get(status, 0) for status in FINAL)

    @property
    def duplicates(self) -> int:
        return (
            self.duplicate_evaluations
            + self.duplicate_checkpoints
            + self.duplicate_mission_evaluations
        )


class Probe:
    """Counts rows of the service's tables from the bench process (read-only queries)."""

    def __init__(self, state_url: str, broker: Path | str) -> None:
        self.state: Engine = create_engine(state_url, pool_pre_ping=True)
        self.broker = broker

    def close(self) -> None:
        self.state.dispose()

    def broker_messages(self) -> int | None:
        """Embedded: rows of ``kombu_message`` (consumed ones too, until the clean-up); Redis:
        messages in its lists (queued) plus the unacked hash (delivered, not acknowledged)."""
        if isinstance(self.broker, Path):
            if not self.broker.exists():
                return 0
            uri = f"file:{self.broker}?mode=ro"
            try:
                with sqlite3.connect(uri, uri=True, timeout=10) as connection:
                    row = connection.execute("SELECT count(*) FROM kombu_message").fetchone()
            except sqlite3.OperationalError as error:
                if "no such table" in str(error):
                    return 0
                return None  # locked for longer than the timeout: skip this sample
            return int(row[0])
        import redis

        client = redis.Redis.from_url(self.broker)
        try:
            total = sum(int(client.llen(key)) for key in client.scan_iter(_type="list"))
            return total + int(client.hlen("unacked"))
        finally:
            client.close()

    def sample(self, at: float) -> Sample:
        with self.state.connect() as connection:
            events = connection.execute(text("SELECT count(*) FROM events")).scalar_one()
            rows = connection.execute(text("SELECT status, count(*) FROM missions GROUP BY status"))
            statuses = {str(status): int(count) for status, count in rows}
        return Sample(at, self.broker_messages(), int(events), statuses)

    def account(self, result: LoadResult) -> None:
        """The end-of-run accounting (see the module docstring, 4) into ``result``."""
        with self.state.connect() as connection:

            def scalar(sql: str) -> int:
                return int(connection.execute(text(sql)).scalar_one() or 0)

            rows = connection.execute(text("SELECT id, status, reason FROM missions")).all()
            result.statuses = dict(Counter(str(status) for _, status, _ in rows))
            for mission_id, status, reason in rows:
                status = str(status)
                kind = result.kinds.get(mission_id, "unknown")
                if status not in FINAL:
                    result.lost += 1
                if status == "failed" and not (reason or "").strip():
                    result.failed_without_reason += 1
                expected = "done" if kind == "tiny" else "failed"
                if status != expected:
                    result.unexpected.append(f"{mission_id} {kind}: {status} ({reason})")
            result.lost += len(set(result.kinds) - {mission_id for mission_id, _, _ in rows})
            result.duplicate_evaluations = scalar(
                "SELECT count(*) FROM (SELECT job_id, steps FROM evaluations "
                "WHERE job_id IS NOT NULL GROUP BY job_id, steps HAVING count(*) > 1) AS d"
            )
            result.duplicate_mission_evaluations = scalar(
                "SELECT count(*) FROM (SELECT mission_id, steps FROM evaluations "
                "WHERE job_id IS NULL GROUP BY mission_id, steps HAVING count(*) > 1) AS d"
            )
            result.duplicate_checkpoints = scalar(
                "SELECT count(*) FROM (SELECT job_id, steps FROM checkpoints "
                "GROUP BY job_id, steps HAVING count(*) > 1) AS d"
            )
            result.jobs = scalar("SELECT count(*) FROM jobs")
            result.progress_events_left = scalar(
                "SELECT count(*) FROM events JOIN missions ON missions.id = events.mission_id "
                "WHERE events.kind = 'progress' "
                "AND missions.status IN ('done', 'failed', 'cancelled')"
            )
            result.retried_jobs = scalar("SELECT count(*) FROM jobs WHERE attempts <> 1")
            result.retried_plans = scalar("SELECT count(*) FROM missions WHERE plan_attempts > 1")
            result.retried_assemblies = scalar(
                "SELECT count(*) FROM missions WHERE assembly_attempts > 1"
            )
            first, last = connection.execute(
                text("SELECT min(created_at), max(updated_at) FROM missions")
            ).one()
        if first is not None and last is not None:
            result.wall = (_timestamp(last) - _timestamp(first)).total_seconds()


def _stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/PID/stat`` after the command name (None: gone, or not Linux)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _descendants(pid: int) -> list[int]:
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").glob("[0-9]*"):
        fields = _stat(int(entry.name))
        if fields is not None:
            parents.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        children = parents.get(todo.pop(), [])
        found += children
        todo += children
    return found


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds so far of process ``pid`` and its live descendants (the API's
    processes when it runs in several; Linux ``/proc``; 0 elsewhere)."""
    total = 0
    for member in (pid, *_descendants(pid)):
        fields = _stat(member)
        if fields is not None:
            total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def _timestamp(value: Any) -> Any:
    """A datetime from a raw column (SQLite hands back ISO strings)."""
    from datetime import datetime

    return datetime.fromisoformat(value) if isinstance(value, str) else value


class Traffic:
    """The pollers of one run in this asyncio loop, the submitters in a process of their own."""

    def __init__(
        self, url: str, result: LoadResult, args: argparse.Namespace, api_pid: int
    ) -> None:
        self.url, self.result, self.args, self.api_pid = url, result, args, api_pid
        self.owned: dict[str, list[str]] = {key: [] for key in KEYS}
        self.stop = asyncio.Event()
        self.submitted = False
        self.polls_started = time.monotonic()
        self.polls_perf = time.perf_counter()
        self.api_cpu_start = cpu_seconds(api_pid)

    async def submit_in_child(self) -> None:
        """Run the submitters in a process of their own (``--submit-to``), recording each
        mission as it is created so that the pollers can read it at once: their work then
        does not delay this loop, which times the pollers' reads."""
        child = await asyncio.create_subprocess_exec(
            sys.executable,
            str(Path(__file__).resolve()),
            "--submit-to",
            self.url,
            "--missions",
            str(self.args.missions),
            stdout=asyncio.subprocess.PIPE,
        )
        assert child.stdout is not None
        async for line in child.stdout:
            record = json.loads(line)
            if "seconds" in record:
                self.result.post_times.append(record["seconds"])
            if "error" in record:
                self.result.post_errors[record["error"]] += 1
            else:
                self.result.kinds[record["id"]] = record["kind"]
                self.owned[record["key"]].append(record["id"])
        if await child.wait() != 0:
            raise RuntimeError(f"the submitting process exited with {child.returncode}")

    async def poller(self, client: httpx.AsyncClient, number: int) -> None:
        """Read a random mission of its own key every ``--interval`` s until told to stop."""
        rng = random.Random(number)
        key = KEYS[number % len(KEYS)]
        headers = {"Authorization": f"Bearer {key}"}
        interval = self.args.interval
        await asyncio.sleep(rng.uniform(0, interval))
        while not self.stop.is_set():
            if not self.owned[key]:
                await asyncio.sleep(0.1)
                continue
            mission_id = rng.choice(self.owned[key])
            start = time.perf_counter()
            try:
                response = await client.get(f"/missions/{mission_id}", headers=headers)
            except httpx.HTTPError as error:
                self.result.get_errors[type(error).__name__] += 1
                continue
            elapsed = time.perf_counter() - start
            self.result.get_times.append(elapsed)
            self.result.get_sent.append(start - self.polls_perf)
            self.result.get_server_times.append(server_seconds(response))
            if not response.is_success:
                self.result.get_errors[str(response.status_code)] += 1
            await asyncio.sleep(max(0.0, interval - elapsed))

    async def loop_lag(self) -> None:
        """Record how late this loop wakes from a 10 ms sleep until told to stop."""
        while not self.stop.is_set():
            start = time.perf_counter()
            await asyncio.sleep(LAG_TICK)
            woke = time.perf_counter()
            self.result.loop_lags.append((start - self.polls_perf, woke - start - LAG_TICK))

    async def sampler(self, probe: Probe, started: float) -> None:
        """Sample the tables every ``--sample`` s; stop the pollers once every mission ended
        (or at ``--limit``), then sample two more clean-up periods for the final counts."""
        args = self.args
        ended_at: float | None = None
        while True:
            now = time.monotonic()
            sample = await asyncio.to_thread(probe.sample, now - started)
            self.result.samples.append(sample)
            ended = sum(sample.statuses.get(status, 0) for status in FINAL)
            if ended_at is None and (
                (ended >= args.missions and self.submitted) or now - started > args.limit
            ):
                ended_at = now
                self.stop.set()
                self.result.poll_seconds = now - self.polls_started
                self.result.api_cpu_seconds = cpu_seconds(self.api_pid) - self.api_cpu_start
                print(f"  all {ended} ended at {now - started:.0f} s; settling", flush=True)
            if ended_at is not None and now - ended_at > 2 * args.cleanup + args.sample:
                return
            if len(self.result.samples) % 10 == 0:
                print(
                    f"  {now - started:.0f} s: {sample.statuses}, broker {sample.broker}, "
                    f"events {sample.events}",
                    flush=True,
                )
            await asyncio.sleep(args.sample)

    async def run(self, probe: Probe) -> None:
        args = self.args
        # Idle connections are dropped after 2 s, before uvicorn's 5 s keep-alive timeout: at
        # httpx's default (5 s, the same) a request now and then raced the server's close and
        # failed with RemoteProtocolError / ReadError, an artefact of the client.
        limits = httpx.Limits(
            max_connections=args.pollers,
            max_keepalive_connections=args.pollers,
            keepalive_expiry=KEEPALIVE_EXPIRY,
        )
        started = time.monotonic()
        self.polls_started = started
        self.polls_perf = time.perf_counter()
        async with httpx.AsyncClient(base_url=self.url, timeout=30, limits=limits) as readers:
            pollers = [asyncio.create_task(self.poller(readers, n)) for n in range(args.pollers)]
            sampler = asyncio.create_task(self.sampler(probe, started))
            lag = asyncio.create_task(self.loop_lag())
            await self.submit_in_child()
            self.submitted = True
            self.result.submit_seconds = time.monotonic() - started
            print(
                f"  {len(self.result.kinds)} submitted in {self.result.submit_seconds:.1f} s",
                flush=True,
            )
            await sampler
            self.stop.set()
            await asyncio.gather(*pollers, lag)


async def submit_all(url: str, missions: int) -> None:
    """The submitting process: each key submits its share of ``missions`` one after the other
    (429: wait as told, again), printing a JSON line per POST (its time, the new mission or
    the error)."""

    def report(record: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(record) + "\n")
        sys.stdout.flush()

    async def submitter(client: httpx.AsyncClient, key: str, indices: list[int]) -> None:
        headers = {"Authorization": f"Bearer {key}"}
        for index in indices:
            kind, document = load_mission(index)
            for _ in range(20):
                start = time.perf_counter()
                try:
                    response = await client.post("/missions", json=document, headers=headers)
                except httpx.HTTPError as error:
                    report({"error": type(error).__name__})
                    await asyncio.sleep(1)
                    continue
                seconds = time.perf_counter() - start
                if response.status_code == 201:
                    report(
                        {"seconds": seconds, "key": key, "id": response.json()["id"], "kind": kind}
                    )
                    break
                report({"seconds": seconds, "error": str(response.status_code)})
                await asyncio.sleep(float(response.headers.get("Retry-After", "1")))

    limits = httpx.Limits(keepalive_expiry=KEEPALIVE_EXPIRY)
    async with httpx.AsyncClient(base_url=url, timeout=60, limits=limits) as client:
        shares = [list(range(i, missions, len(KEYS))) for i in range(len(KEYS))]
        await asyncio.gather(
            *(submitter(client, k, share) for k, share in zip(KEYS, shares, strict=True))
        )


def run_load(
    args: argparse.Namespace, backend: str, parent: Path, api_processes: int = 1, run: int = 0
) -> LoadResult:
    """One backend (``embedded`` or ``servers``) with the API in ``api_processes`` processes:
    a fresh state, the API, two workers, the traffic, the accounting; every process stopped
    before it returns."""
    servers = backend == "servers"
    options = argparse.Namespace(
        timesteps=TINY_LOAD["training"]["n_timesteps"],
        redis=args.redis if servers else None,
        postgres=args.postgres if servers else None,
    )
    result = LoadResult(
        backend, args.missions, load_before=os.getloadavg(), api_processes=api_processes
    )
    extra = {
        "LTLNAV_API_KEYS": json.dumps(KEYS),
        "LTLNAV_QUOTA_ACTIVE_MISSIONS": "0",
        "LTLNAV_QUOTA_SUBMISSIONS_PER_MINUTE": "0",
        "LTLNAV_BROKER_CLEANUP_SECONDS": str(args.cleanup),
        "LTLNAV_KEEP_FAILED_DAYS": "0",
        "LTLNAV_API_PROCESSES": str(api_processes),
    }
    began = time.monotonic()
    with ExitStack() as stack:
        name = f"load-{backend}-{run}"
        layout = stack.enter_context(phase_layout(parent, name, options))
        layout = dataclasses.replace(layout, extra=extra)
        api: list[subprocess.Popen[bytes]] = []
        url = stack.enter_context(api_server(layout, api))  # migrated once /healthz answers
        workers = [
            stack.enter_context(start_worker(layout, 1, f"load-{number}", args.nice))
            for number in range(WORKERS)
        ]
        stack.callback(interrupt, [proc for proc, _ in workers])  # stop both at once
        for proc, log in workers:
            wait_ready(proc, log)
        data = layout.root / "data"
        state_url = layout.postgres or f"sqlite:///{data / 'ltlnav.db'}"
        broker: Path | str = layout.env()["LTLNAV_BROKER_URL"] if servers else data / "broker.db"
        probe = Probe(state_url, broker)
        stack.callback(probe.close)
        ready = time.monotonic() - began
        print(f"{backend}: API {url}, {WORKERS} workers ready in {ready:.0f} s", flush=True)
        asyncio.run(Traffic(url, result, args, api[0].pid).run(probe))
        probe.account(result)
        stopping = time.monotonic()
    print(f"{backend}: processes stopped in {time.monotonic() - stopping:.0f} s", flush=True)
    result.load_after = os.getloadavg()
    return result


def quantiles_ms(samples: list[float]) -> tuple[float, float, float]:
    """p50, p95 and p99 in milliseconds (nearest rank)."""
    if not samples:
        return (float("nan"),) * 3
    ordered = sorted(samples)

    def rank(q: float) -> float:
        return 1000 * ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]

    return 1000 * statistics.median(ordered), rank(0.95), rank(0.99)


def server_seconds(response: httpx.Response) -> float:
    """The API's time for ``response`` from its ``Server-Timing: app;dur=MS`` header (NaN
    without one)."""
    for metric in response.headers.get("server-timing", "").split(","):
        name, _, duration = metric.strip().partition(";dur=")
        if name == "app":
            return float(duration) / 1000
    return float("nan")


def _get_phases(result: LoadResult, times: list[float]) -> tuple[list[float], list[float]]:
    """``times`` (one per GET: the client's or the API's) of the requests sent while missions
    were being submitted, and after."""
    during: list[float] = []
    after: list[float] = []
    for sent, elapsed in zip(result.get_sent, times, strict=True):
        (during if sent < result.submit_seconds else after).append(elapsed)
    return during, after


def _lag_phases(result: LoadResult) -> tuple[list[float], list[float]]:
    """The bench loop's lags while missions were being submitted, and after."""
    during = [lag for when, lag in result.loop_lags if when < result.submit_seconds]
    after = [lag for when, lag in result.loop_lags if when >= result.submit_seconds]
    return during, after


def _errors(counter: Counter[str]) -> str:
    return ", ".join(f"{k}: {v}" for k, v in sorted(counter.items())) or "0"


def table_rows(result: LoadResult) -> list[tuple[str, str]]:
    """(measure, value) rows of one backend, in the order of the table."""
    broker = [s.broker for s in result.samples if s.broker is not None]
    events = [s.events for s in result.samples]
    p50, p95, p99 = quantiles_ms(result.get_times)
    q50, _, q99 = quantiles_ms(result.post_times)
    statuses = result.statuses
    requests = len(result.get_times) + len(result.post_times)
    failed = statuses.get("failed", 0)
    expected_failures = sum(1 for kind in result.kinds.values() if kind != "tiny")
    return [
        ("API processes", str(result.api_processes)),
        ("missions submitted / accounted for", f"{len(result.kinds)} / {result.ended}"),
        ("done", str(statuses.get("done", 0))),
        (
            "failed (with a reason) / expected",
            f"{failed} ({failed - result.failed_without_reason}) / {expected_failures}",
        ),
        ("lost (not ended) / other status", f"{result.lost} / {len(result.unexpected)}"),
        ("wall time (first POST -> last end)", f"{result.wall:.0f} s"),
        ("missions / min", f"{60 * result.ended / max(result.wall, 1e-9):.1f}"),
        ("POST /missions p50 / p99 (10 keys)", f"{q50:.0f} / {q99:.0f} ms"),
        (
            "POST non-201 / submit time",
            f"{_errors(result.post_errors)} / {result.submit_seconds:.0f} s",
        ),
        (
            "GET /missions/{id} p50 / p95 / p99",
            f"{p50:.1f} / {p95:.1f} / {p99:.1f} ms",
        ),
        (
            "GET requests / non-2xx",
            f"{len(result.get_times)} ({len(result.get_times) / max(result.poll_seconds, 1e-9):.0f}"
            f"/s) / {_errors(result.get_errors)}",
        ),
        (
            "GET p99 in the API (Server-Timing)",
            f"{quantiles_ms(result.get_server_times)[2]:.1f} ms",
        ),
        (
            "GET p99 while submitting / after",
            " / ".join(
                f"{quantiles_ms(part)[2]:.1f} ms" for part in _get_phases(result, result.get_times)
            ),
        ),
        (
            "the API's p99 while submitting / after",
            " / ".join(
                f"{quantiles_ms(part)[2]:.1f} ms"
                for part in _get_phases(result, result.get_server_times)
            ),
        ),
        (
            "bench loop lag p99 while submitting / after",
            " / ".join(f"{quantiles_ms(part)[2]:.1f} ms" for part in _lag_phases(result)),
        ),
        ("p99 < 50 ms", "met" if p99 < 50 else "MISSED"),
        (
            "API CPU per request (GET + POST)",
            f"{1000 * result.api_cpu_seconds / max(requests, 1):.1f} ms "
            f"({100 * result.api_cpu_seconds / max(result.poll_seconds, 1e-9):.0f} % of a core)",
        ),
        (
            "broker messages max / final",
            f"{max(broker, default=0)} / {broker[-1] if broker else '-'}",
        ),
        (
            "event rows max / final (progress left)",
            f"{max(events, default=0)} / {events[-1] if events else '-'} "
            f"({result.progress_events_left})",
        ),
        (
            "duplicate steps (eval / ckpt / mission eval)",
            f"{result.duplicate_evaluations} / {result.duplicate_checkpoints} / "
            f"{result.duplicate_mission_evaluations}",
        ),
        (
            "begun twice: jobs / plannings / assemblies",
            f"{result.retried_jobs} of {result.jobs} / {result.retried_plans} / "
            f"{result.retried_assemblies}",
        ),
        (
            "load average before -> after",
            f"{result.load_before[0]:.1f} -> {result.load_after[0]:.1f}",
        ),
    ]


def print_table(results: list[LoadResult]) -> None:
    """One table, one column per backend."""
    names = {"embedded": "embedded (SQLite + sqla)", "servers": "Redis + PostgreSQL"}
    columns = [table_rows(result) for result in results]
    rows = [
        ("measure", *(names[r.backend] for r in results)),
        *(
            (columns[0][i][0], *(column[i][1] for column in columns))
            for i in range(len(columns[0]))
        ),
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    rows.insert(1, tuple("-" * width for width in widths))
    for row in rows:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)))
    for result in results:
        for line in result.unexpected[:10]:
            print(f"{result.backend}: unexpected: {line}")


def parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--missions", type=int, default=500, help="tiny missions per backend")
    parser.add_argument("--pollers", type=int, default=50, help="concurrent GET clients")
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between reads")
    parser.add_argument("--sample", type=float, default=3.0, help="seconds between samples")
    parser.add_argument("--cleanup", type=float, default=5.0, help="broker clean-up period")
    parser.add_argument("--limit", type=float, default=3600.0, help="give up after (s)")
    parser.add_argument(
        "--nice", type=int, default=0, help="run the workers under nice -n NICE (0: not)"
    )
    parser.add_argument("--redis", help="Redis URL of the broker (.../N); results in db N+1")
    parser.add_argument("--postgres", help="PostgreSQL server URL (no database name)")
    parser.add_argument(
        "--backends",
        nargs="+",
        choices=["embedded", "servers"],
        help="default: embedded, and servers when --redis and --postgres are given",
    )
    parser.add_argument("--submit-to", help=argparse.SUPPRESS)  # the submitting process
    parser.add_argument(
        "--api-processes",
        type=int,
        nargs="+",
        default=[1],
        help="API processes (LTLNAV_API_PROCESSES); several values run each backend once per "
        "value, side by side in the table",
    )
    return parser


def main(argv: list[str] | None = None) -> list[LoadResult]:
    stop_on_sigterm()
    args = parser().parse_args(argv)
    if args.submit_to:
        asyncio.run(submit_all(args.submit_to, args.missions))
        return []
    backends = args.backends or (
        ["embedded", "servers"] if args.redis and args.postgres else ["embedded"]
    )
    if "servers" in backends and not (args.redis and args.postgres):
        raise SystemExit("--backends servers needs --redis and --postgres")
    command = shlex.join([Path(sys.executable).name, *sys.argv])
    print(machine_note(), flush=True)
    results: list[LoadResult] = []
    with tempfile.TemporaryDirectory(prefix="ltlnav-load-") as tmp:
        for backend in backends:
            for processes in args.api_processes:
                run = len(results)
                results.append(run_load(args, backend, Path(tmp), processes, run))
    print(f"\nltlnav service load: {args.missions} tiny missions per backend, 10 API keys, ")
    print(
        f"{WORKERS} x `{f'nice -n {args.nice} ' if args.nice else ''}ltlnav worker "
        f"--concurrency 1`, {args.pollers} pollers every "
        f"{args.interval:g} s, LTLNAV_KEEP_FAILED_DAYS=0, clean-up every {args.cleanup:g} s"
    )
    print(f"command: {command}")
    print(machine_note().replace(" at start", " now"))
    print_table(results)
    return results


if __name__ == "__main__":
    main()
