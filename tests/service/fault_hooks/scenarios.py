"""The fault scenarios, each on a ``Cluster`` at a ``Scale``: the test suite runs them small and
asserts on what they return, ``bench/faults.py`` runs them at full scale and prints the rows.

A scenario starts the workers it needs, injects its fault at a chosen moment, waits for the
mission to end and measures: the steps each interrupted job had done before the fault against
the step it resumed from (at most one checkpoint interval may be lost), rows written twice,
and the time from the fault until the interrupted work ran again.
"""

from __future__ import annotations

import asyncio
import errno
import json
import os
import signal
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import update

from service import repository
from service.models import Job, JobStatus, MissionStatus
from tests.service.fault_hooks.cluster import Cluster, Snapshot, free_port, kill_group
from workers.checkpoints import checkpoint_steps as checkpoints_steps
from workers.checkpoints import checkpoints


@dataclass(frozen=True)
class Scale:
    """How big the missions and the faults are."""

    budget: int
    """Training steps of each sub-task."""
    interval: int
    """Steps between checkpoints (and evaluations)."""
    outage_seconds: float
    """How long the database is unavailable."""
    stall_seconds: float
    """How long a stalled planning or assembly lasts before its worker is killed."""
    timeout: float
    """The longest a mission may take after its fault."""
    task: str | None = None
    """The mission's formula (None: the tiny mission's, four sub-tasks)."""
    handover_rounds: int = 0
    """Rounds of hand-over repair (none: the faults are about training and assembly)."""
    pollers: int = 50
    poll_seconds: float = 20.0

    def training(self) -> dict[str, Any]:
        """The mission's overrides: its task and training section."""
        return {
            "task": self.task,
            "n_timesteps": self.budget,
            "eval_freq": self.interval,
            "checkpoint_freq": self.interval,
            "handover_rounds": self.handover_rounds,
        }


TEST = Scale(
    budget=300,
    interval=100,
    outage_seconds=15,
    stall_seconds=30,
    timeout=240,
    task="[]!obstacle && <>(a && <>b)",
)
"""The test suite's: two sub-tasks that train in seconds."""

FULL = Scale(budget=1000, interval=250, outage_seconds=90, stall_seconds=60, timeout=900)
"""``bench/faults.py``'s: the four sub-tasks of the tiny world, minutes of training each, a
90 s database outage."""


@dataclass
class FaultRow:
    """What one fault did (one row of ``bench/faults.py``)."""

    deployment: str
    fault: str
    when: str = ""
    status: str = ""
    reason: str | None = None
    before: dict[int, int] = field(default_factory=dict)
    """Steps done (recorded) by each interrupted job when the fault came, by sub-task."""
    tokens: dict[int, int] = field(default_factory=dict)
    """The attempt each interrupted job was at when the fault came."""
    resumed: dict[int, int] = field(default_factory=dict)
    """The step each interrupted job's finishing attempt resumed from (``before``: the
    interrupted attempt itself finished, or a later one reused its result)."""
    interval: int = 0
    duplicates: int = 0
    recover_seconds: float | None = None
    attempts: dict[int, int] = field(default_factory=dict)
    """Attempts of every job of round 0 at the end, by sub-task."""
    notes: list[str] = field(default_factory=list)
    facts: dict[str, Any] = field(default_factory=dict)
    """What a scenario's checks need beyond the row (named by the scenario)."""

    @property
    def lost(self) -> int:
        """The most steps any interrupted job had to train again."""
        return max((self.before[k] - self.resumed.get(k, 0) for k in self.before), default=0)

    @property
    def retrained(self) -> int:
        """Steps trained again, over every interrupted job."""
        return sum(max(self.before[k] - self.resumed.get(k, 0), 0) for k in self.before)

    def finish(self, cluster: Cluster, found: Snapshot) -> FaultRow:
        """Fill in the outcome from the mission's final rows."""
        self.status = found.mission.status.value
        self.reason = found.mission.reason
        self.duplicates = cluster.duplicates(found.mission.id)
        self.attempts = {j.index: j.attempts for j in found.jobs if j.repair_round == 0}
        claims: dict[int, float] = {}
        for kind, payload, at in cluster.timed_events(found.mission.id):
            if kind == "job" and payload.get("status") == "running" and not payload.get("round"):
                claims[int(payload["index"])] = at
        for job in found.jobs:
            if job.repair_round == 0 and job.index in self.before and job.result:
                self.resumed[job.index] = int(job.result["resumed_from"])
                if job.attempts == self.tokens.get(job.index):  # the same attempt went on
                    self.resumed[job.index] = self.before[job.index]
                    continue
                stored = Path(job.out_dir) / "result.json"
                if stored.is_file() and stored.stat().st_mtime < claims.get(job.index, 0.0):
                    # the last attempt found the result an earlier one wrote: nothing redone
                    self.resumed[job.index] = self.before[job.index]
                    self.notes.append(f"sub-task {job.index}: result reused")
        return self


def _mid_training(
    cluster: Cluster, mission_id: str, budget: int, saved: int = 1
) -> Callable[[], Snapshot | None]:
    """A ``wait`` condition: every running job has at least ``saved`` checkpoints and none
    has finished its budget."""

    def ready() -> Snapshot | None:
        found = cluster.snapshot(mission_id)
        running = [j for j in found.jobs if j.status == JobStatus.running]
        if not running:
            return None
        enough = all(len(found.checkpoints[j.id]) >= saved for j in running)
        short = all(found.latest(j) < budget for j in running)
        return found if enough and short else None

    return ready


def _running_steps(found: Snapshot) -> dict[int, int]:
    """Steps done (the recorded progress or newest checkpoint) of each running job."""
    return {
        j.index: max(j.steps_done, found.latest(j))
        for j in found.jobs
        if j.status == JobStatus.running and j.repair_round == 0
    }


def _watch_recovery(
    cluster: Cluster, mission_id: str, t0: float, recovered: Callable[[Snapshot], bool]
) -> Callable[[], Snapshot | None]:
    """``wait`` condition for the end of the mission that also notes (in ``times``) when
    ``recovered`` first held."""
    times: list[float] = []

    def until() -> Snapshot | None:
        found = cluster.snapshot(mission_id)
        if not times and (recovered(found) or found.mission.status in repository.FINAL_STATES):
            times.append(time.monotonic() - t0)
        if found.mission.status in repository.FINAL_STATES:
            return found
        return None

    until.times = times  # type: ignore[attr-defined]
    return until


def _resumed_past(attempts: dict[int, int]) -> Callable[[Snapshot], bool]:
    """Recovered: every job in ``attempts`` is done or running a later attempt."""

    def check(found: Snapshot) -> bool:
        jobs = {j.index: j for j in found.jobs if j.repair_round == 0}
        return all(
            jobs[k].status == JobStatus.done
            or (jobs[k].status == JobStatus.running and jobs[k].attempts > n)
            for k, n in attempts.items()
        )

    return check


def _end(
    cluster: Cluster,
    row: FaultRow,
    mission_id: str,
    t0: float,
    timeout: float,
    recovered: Callable[[Snapshot], bool],
) -> FaultRow:
    until = _watch_recovery(cluster, mission_id, t0, recovered)
    found = cluster.wait(until, timeout, f"final ({row.fault})")
    times: list[float] = until.times  # type: ignore[attr-defined]
    row.recover_seconds = times[0] if times else None
    return row.finish(cluster, found)


def training_child_sigkill(cluster: Cluster, scale: Scale) -> FaultRow:
    """SIGKILL the prefork child running one training job (its pid is in ``Job.worker``)."""
    cluster.start_worker()
    mission_id, _ = cluster.submit(**scale.training())
    found = cluster.wait(_mid_training(cluster, mission_id, scale.budget), 240, "training")
    job = next(j for j in found.jobs if j.status == JobStatus.running)
    assert job.worker is not None
    pid = int(job.worker.rsplit(":", 1)[1])
    row = FaultRow(cluster.kind, "SIGKILL training child", interval=scale.interval)
    row.before = {job.index: max(job.steps_done, found.latest(job))}
    row.tokens = {job.index: job.attempts}
    row.when = f"sub-task {job.index} at {row.before[job.index]}/{scale.budget} steps"
    os.kill(pid, signal.SIGKILL)
    t0 = time.monotonic()
    return _end(cluster, row, mission_id, t0, scale.timeout, _resumed_past({job.index: 1}))


def worker_sigkill_each_phase(cluster: Cluster, scale: Scale) -> list[FaultRow]:
    """One mission, its whole worker SIGKILLed during planning, then during training, then
    during assembly, a new worker started each time."""
    rows: list[FaultRow] = []
    stall = str(scale.stall_seconds)
    first = cluster.start_worker({"FAULT_STALL_PLAN": stall})
    mission_id, _ = cluster.submit(**scale.training())

    def status_is(status: MissionStatus) -> Callable[[], Snapshot | None]:
        def check() -> Snapshot | None:
            found = cluster.snapshot(mission_id)
            return found if found.mission.status == status else None

        return check

    cluster.wait(status_is(MissionStatus.planning), 240, "planning")
    time.sleep(1.0)  # inside the planning step
    row = FaultRow(cluster.kind, "SIGKILL worker group", "planning", interval=scale.interval)
    kill_group(first)
    t0 = time.monotonic()
    second = cluster.start_worker()
    cluster.wait(status_is(MissionStatus.training), scale.timeout, "training again")
    row.recover_seconds = time.monotonic() - t0
    rows.append(row)

    found = cluster.wait(_mid_training(cluster, mission_id, scale.budget), 240, "mid-training")
    row = FaultRow(cluster.kind, "SIGKILL worker group", interval=scale.interval)
    row.before = _running_steps(found)
    attempts = row.tokens = {j.index: j.attempts for j in found.jobs if j.index in row.before}
    row.when = "training: " + ", ".join(
        f"sub-task {k} at {s}/{scale.budget}" for k, s in sorted(row.before.items())
    )
    kill_group(second)
    t0 = time.monotonic()
    third = cluster.start_worker({"FAULT_STALL_ASSEMBLE": stall})
    cluster.wait(
        lambda: f if _resumed_past(attempts)(f := cluster.snapshot(mission_id)) else None,
        scale.timeout,
        "training resumed",
    )
    row.recover_seconds = time.monotonic() - t0
    rows.append(row)

    cluster.wait(status_is(MissionStatus.evaluating), scale.timeout, "assembling")
    time.sleep(1.0)
    row = FaultRow(cluster.kind, "SIGKILL worker group", "assembly", interval=scale.interval)
    kill_group(third)
    t0 = time.monotonic()
    cluster.start_worker()
    _end(cluster, row, mission_id, t0, scale.timeout, lambda f: False)
    # every row reports the mission's end; training's also what its jobs resumed from
    for earlier in rows:
        earlier.finish(cluster, cluster.snapshot(mission_id))
    return [*rows, row]


def _lock_sqlite(path: Path, seconds: float, stop: threading.Event) -> threading.Thread:
    """Hold an exclusive transaction on the SQLite file for ``seconds`` (a thread)."""
    locked = threading.Event()

    def hold() -> None:
        connection = sqlite3.connect(path, timeout=60, isolation_level=None)
        try:
            connection.execute("BEGIN EXCLUSIVE")
            locked.set()
            stop.wait(seconds)
            connection.execute("ROLLBACK")
        finally:
            connection.close()

    thread = threading.Thread(target=hold, daemon=True, name="fault-sqlite-lock")
    thread.start()
    locked.wait(60)
    return thread


def _fill_disk(filler: Path) -> int:
    """Write ``filler`` until its filesystem is full (``ENOSPC``); the bytes written."""
    written = 0
    with filler.open("wb", buffering=0) as out:
        for chunk in (1 << 20, 4096, 512, 1):
            block = bytes(chunk)
            try:
                while True:
                    written += out.write(block)
            except OSError as error:
                if error.errno != errno.ENOSPC:
                    raise
    return written


FELT_WITHIN = 30.0
"""Seconds a full disk stays full past ``outage_seconds`` until the workers' logs show a write
it refused (``database_outage``'s ``felt``): a write that fits pages the database already holds
is not refused, and a short outage can pass without any other."""


def database_outage(
    cluster: Cluster, scale: Scale, full_disk: Path | None = None, felt: str | None = None
) -> FaultRow:
    """The database unavailable to the workers for ``outage_seconds`` mid-training: PostgreSQL
    behind a paused proxy (connections cut and refused); SQLite locked by an exclusive
    transaction of another process, or, with ``full_disk`` (the folder of the state file, on a
    small filesystem of its own), that filesystem filled up (every write refused: "database or
    disk is full"), and with ``felt`` kept full until the logs show that refusal (at most
    ``FELT_WITHIN`` s more). The jobs must keep training and keep their attempt."""
    cluster.start_worker()
    mission_id, _ = cluster.submit(**scale.training())
    found = cluster.wait(_mid_training(cluster, mission_id, scale.budget), 240, "training")
    what = "state disk full" if full_disk is not None else "database down"
    row = FaultRow(cluster.kind, f"{what} {scale.outage_seconds:.0f} s")
    row.interval = scale.interval
    row.before = _running_steps(found)
    attempts = row.tokens = {j.index: j.attempts for j in found.jobs if j.index in row.before}
    row.when = "training: " + ", ".join(
        f"sub-task {k} at {s}/{scale.budget}" for k, s in sorted(row.before.items())
    )
    folders = {j.index: Path(j.out_dir) / "checkpoints" for j in found.jobs}
    t0 = time.monotonic()
    stamp = time.time()
    stop = threading.Event()
    if cluster.db_proxy is not None:
        cluster.db_proxy.pause()
        stop.wait(scale.outage_seconds)
        cluster.db_proxy.resume()
    elif full_disk is not None:
        filler = full_disk / "filler"
        row.facts["filled bytes"] = _fill_disk(filler)
        stop.wait(scale.outage_seconds)
        deadline = time.monotonic() + FELT_WITHIN
        while felt is not None and felt not in cluster.tail(10**6):
            if time.monotonic() > deadline:
                break
            stop.wait(0.5)
        filler.unlink()
        row.facts["full seconds"] = round(time.monotonic() - t0, 1)
    else:
        path = Path(cluster.settings.database_url.split(":///", 1)[1])
        _lock_sqlite(path, scale.outage_seconds, stop).join()
    during = sum(
        1
        for k in row.before
        for model, _, _ in checkpoints(folders[k])
        if model.stat().st_mtime > stamp
    )
    row.notes.append(f"{during} checkpoint files written during the outage")
    row.recover_seconds = None
    _end(cluster, row, mission_id, t0, scale.timeout, lambda f: _progressed(f, row.before))
    row.notes.append(f"attempts before {attempts}")
    return row


def _progressed(found: Snapshot, before: dict[int, int]) -> bool:
    jobs = {j.index: j for j in found.jobs if j.repair_round == 0}
    return all(
        jobs[k].status == JobStatus.done or jobs[k].steps_done > s for k, s in before.items()
    )


def disk_full_at_checkpoint(cluster: Cluster, scale: Scale, marker: Path) -> FaultRow:
    """``OSError(ENOSPC)`` from the second checkpoint of the first job to reach it (once): the
    job is put back after its backoff and completes from its checkpoint."""
    cluster.start_worker(
        {"FAULT_ENOSPC_ONCE": str(marker), "FAULT_ENOSPC_AFTER": str(2 * scale.interval)}
    )
    mission_id, _ = cluster.submit(**scale.training())
    cluster.wait(lambda: True if marker.is_file() else None, 240, "disk full injected")
    t0 = time.monotonic()
    at = int(marker.read_text().split()[0])
    row = FaultRow(cluster.kind, "disk full at checkpoint", interval=scale.interval)
    failed: list[int] = []

    def recovered(found: Snapshot) -> bool:
        again = [j for j in found.jobs if j.attempts >= 2]
        if again and not failed:
            failed.append(again[0].index)
        return bool(again) and again[0].status in (JobStatus.running, JobStatus.done)

    _end(cluster, row, mission_id, t0, scale.timeout, recovered)
    if failed:
        row.before, row.tokens = {failed[0]: at}, {failed[0]: 1}
        row.finish(cluster, cluster.snapshot(mission_id))
    row.when = f"checkpoint at {at} steps" + (f" of sub-task {failed[0]}" if failed else "")
    return row


def truncated_files(cluster: Cluster, scale: Scale) -> FaultRow:
    """Kill the worker mid-training, then cut short ``plan.json``, the newest checkpoint model
    of a running job and a ``result.json`` in its folder; a new worker completes the mission
    (the plan made again, the checkpoint skipped, the result written anew)."""
    first = cluster.start_worker()
    mission_id, _ = cluster.submit(**scale.training())
    found = cluster.wait(_mid_training(cluster, mission_id, scale.budget, 2), 240, "training")
    kill_group(first)
    found = cluster.snapshot(mission_id)
    row = FaultRow(cluster.kind, "truncated files", interval=scale.interval)
    row.before = _running_steps(found)
    row.tokens = {j.index: j.attempts for j in found.jobs if j.index in row.before}
    job = next(j for j in found.jobs if j.status == JobStatus.running)
    folder = Path(job.out_dir)
    plan = folder.parent / "plan.json"
    model = checkpoints(folder / "checkpoints")[0][0]
    for path in (plan, model):
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    (folder / "result.json").write_text(json.dumps({"subtask": job.index, "steps": 1})[:20])
    row.when = f"plan.json, {model.name} and result.json of sub-task {job.index}"
    t0 = time.monotonic()
    cluster.start_worker()
    _end(cluster, row, mission_id, t0, scale.timeout, _resumed_past({job.index: job.attempts}))
    try:
        json.loads(plan.read_text())
        result = json.loads((folder / "result.json").read_text())
        row.notes.append(f"plan.json valid again; result.json steps {result['steps']}")
    except ValueError as error:
        row.notes.append(f"still damaged: {error}")
    row.facts.update(index=job.index, damaged=checkpoints_steps(model))
    return row


def poison_mission(
    cluster: Cluster, scale: Scale, name: str = "poison", dead_broker: str | None = None
) -> list[FaultRow]:
    """A mission whose planning kills its process every time, beside a good one on the same
    worker: the first fails with "planning: gave up after N attempts", the second completes.
    With ``dead_broker`` the good one is submitted while the broker is unreachable (a closed
    port, an unopenable file): stored and queued, the workers' reconciler sends it."""
    cluster.start_worker({"FAULT_POISON": name})
    poison, _ = cluster.submit(name=name, **scale.training())
    good, error = cluster.submit(broker_url=dead_broker, **scale.training())
    t0 = time.monotonic()
    bad_row = FaultRow(cluster.kind, "poison mission", "every plan attempt")
    fault = "broker down at submit" if dead_broker else "beside the poison"
    good_row = FaultRow(cluster.kind, fault, interval=scale.interval)
    good_row.when = "submit: " + (error or "sent")[:50]
    good_row.notes.append(f"status after submit: {cluster.snapshot(good).mission.status.value}")

    def sent(found: Snapshot) -> bool:
        return found.mission.status != MissionStatus.queued

    _end(cluster, good_row, good, t0, scale.timeout, sent)
    _end(cluster, bad_row, poison, t0, scale.timeout, lambda f: False)
    events = [p.get("reason") or "" for k, p in cluster.events(poison) if k == "status"]
    bad_row.notes.append("event: " + (events[-1] if events else "none"))
    return [bad_row, good_row]


def forced_reclaim(cluster: Cluster, scale: Scale, skew_seconds: float = 0.0) -> FaultRow:
    """Two workers (with ``skew_seconds``, the second's clock runs that far ahead: on the
    database clock it must not reclaim live jobs). Mid-training a job's attempt is forced on
    (its attempts + 1, as a second runner's claim): the first runner must write no row and no
    file from then on; once the forced runner stops beating, the job is reclaimed and
    completes."""
    cluster.start_worker(concurrency=1)
    skewed = {"FAULT_CLOCK_AHEAD": str(skew_seconds)} if skew_seconds else {}
    cluster.start_worker(skewed, concurrency=1)
    mission_id, _ = cluster.submit(**scale.training())
    found = cluster.wait(_mid_training(cluster, mission_id, scale.budget), 240, "training")
    job = next(j for j in found.jobs if j.status == JobStatus.running)
    row = FaultRow(cluster.kind, "forced second runner", interval=scale.interval)
    if skew_seconds:
        row.fault += f" (+{skew_seconds:.0f} s clock)"
    row.before = {job.index: max(job.steps_done, found.latest(job))}
    row.tokens = {job.index: job.attempts}
    row.when = f"sub-task {job.index} at {row.before[job.index]}/{scale.budget} steps"
    token = job.attempts + 1
    with cluster.db.session() as session:
        session.execute(update(Job).where(Job.id == job.id).values(attempts=token))
    t0 = time.monotonic()
    stamp = time.time()
    rows_then = _row_ids(cluster, mission_id, job.id)
    hold = max(4 * cluster.settings.heartbeat_seconds, 3.0)
    while time.monotonic() - t0 < hold:  # the forced runner beats; the first must stop
        with cluster.db.session() as session:
            repository.holds_job(session, job.id, token)
        time.sleep(cluster.settings.heartbeat_seconds / 2)
    late_rows = _row_ids(cluster, mission_id, job.id) - rows_then
    late_files = [
        p.relative_to(job.out_dir)
        for p in Path(job.out_dir).rglob("*")
        if p.is_file()
        and p.stat().st_mtime > stamp + 0.5
        and "logs" not in p.parts
        and ".partial" not in p.name
    ]
    row.notes.append(f"stale attempt wrote {len(late_rows)} rows, {len(late_files)} files")
    row.notes.extend(str(p) for p in late_files[:5])
    _end(cluster, row, mission_id, t0, scale.timeout, _resumed_past({job.index: token}))
    stale = [p for k, p in cluster.events(mission_id) if p.get("reason") == "stale heartbeat"]
    row.notes.append(f"{len(stale)} stale-heartbeat reclaims")
    return row


def _row_ids(cluster: Cluster, mission_id: str, job_id: int) -> set[tuple[str, int]]:
    found = cluster.snapshot(mission_id)
    return {("evaluation", p.id) for p in found.curves[job_id]} | {
        ("checkpoint", c.id) for c in found.checkpoints[job_id]
    }


@dataclass
class Polls:
    """What the pollers of ``api_restart`` saw."""

    kill_at: float = 0.0
    killed_at: float = 0.0
    """When the killed API process was gone."""
    back_at: float | None = None
    """When the first 200 to a request sent after the kill came."""
    seen: list[tuple[int, float, float, int]] = field(default_factory=list)
    """``(poller, sent, answered, status)``, times from the start of polling; status 0: no
    answer (connection refused, reset, timed out)."""


def api_restart(cluster: Cluster, scale: Scale) -> tuple[FaultRow, Polls]:
    """``scale.pollers`` clients poll GET /missions/{id} for ``scale.poll_seconds`` while the
    API process is SIGKILLed and started again (a quarter of the way in)."""
    import httpx

    port = free_port()
    api = cluster.start_api(port)
    base = f"http://127.0.0.1:{port}"

    def up() -> bool | None:
        try:
            httpx.get(f"{base}/healthz", timeout=2)
        except httpx.HTTPError:
            return None
        return True

    cluster.wait(up, 90, "API up")
    mission_id, _ = cluster.submit(**scale.training())  # queued: no worker runs here
    polls = Polls()
    t0 = time.monotonic()

    def polling(now: float, served_again: bool) -> bool:
        """For ``poll_seconds``, and on until this poller was served after the restart (a
        restart on a busy machine may take longer; two minutes at most)."""
        if now < scale.poll_seconds:
            return True
        return bool(polls.kill_at) and not served_again and now < 120.0

    async def poller(k: int, client: httpx.AsyncClient) -> None:
        served_again = False
        while polling(sent := time.monotonic() - t0, served_again):
            try:
                status = (await client.get(f"{base}/missions/{mission_id}")).status_code
            except httpx.HTTPError:
                status = 0
            now = time.monotonic() - t0  # when the answer (or the failure) came
            polls.seen.append((k, sent, now, status))
            if status == 200 and polls.killed_at and sent > polls.killed_at:
                served_again = True
                if polls.back_at is None:
                    polls.back_at = now
            await asyncio.sleep(0.2 if status == 200 else 0.1)

    async def killer() -> None:
        await asyncio.sleep(scale.poll_seconds / 4)
        polls.kill_at = time.monotonic() - t0
        await asyncio.to_thread(kill_group, api)
        polls.killed_at = time.monotonic() - t0
        cluster.start_api(port)

    async def main() -> None:
        limits = httpx.Limits(max_connections=scale.pollers)
        async with httpx.AsyncClient(timeout=5, limits=limits) as client:
            await asyncio.gather(killer(), *(poller(k, client) for k in range(scale.pollers)))

    asyncio.run(main())
    row = FaultRow(cluster.kind, f"API SIGKILL under {scale.pollers} pollers")
    row.when = f"{polls.kill_at:.1f} s into {scale.poll_seconds:.0f} s of polling"
    row.status = "served" if polls.back_at is not None else "not back"
    if polls.back_at is not None:
        row.recover_seconds = polls.back_at - polls.kill_at
    bad = [s for _, _, _, s in polls.seen if s != 200]
    row.notes.append(f"{len(polls.seen)} polls, {len(bad)} not 200 ({sorted(set(bad))})")
    return row, polls
