"""Fault bench: the fault suite's scenarios at full scale, one table row per fault.

Run with ``.venv/bin/python bench/faults.py`` (both deployments: the embedded defaults, and
Redis + PostgreSQL on 127.0.0.1 when they answer) or ``--deployments embedded`` and
``--only child,outage`` (``statedisk``: the disk of the state full for ``--outage`` seconds:
the SQLite file's, or the PostgreSQL database's tablespace; needs root to mount a small tmpfs,
and a PostgreSQL server on this machine). Each scenario gets
fresh processes (``tests.service.fault_hooks``: real ``celery worker`` processes with injected
faults, real SIGKILL), a fresh data folder and, on PostgreSQL, a fresh database; every process
it started is killed when it ends.

Columns: the fault and when it came; how the mission ended; ``lost/interval``: the most steps
an interrupted job had done before the fault beyond the step it resumed from, against the
checkpoint interval (at most one interval may be lost); ``retrained``: those steps over every
interrupted job; ``dup``: rows written twice (evaluation or checkpoint rows of a job at the
same steps; must be 0); ``recover``: seconds from the fault until the interrupted work ran
again (a new attempt, progress, or the next step), or the API answered again.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.service.fault_hooks import scenarios
from tests.service.fault_hooks.cluster import (
    Cluster,
    free_port,
    make_cluster,
    postgres_database,
    server_owns,
    small_filesystem,
)
from tests.service.fault_hooks.scenarios import FULL, FaultRow, Scale

KNOBS = {
    "LTLNAV_HEARTBEAT_SECONDS": "2",
    "LTLNAV_STALE_AFTER_SECONDS": "15",
    "LTLNAV_RECONCILE_SECONDS": "2",
    "LTLNAV_REQUEUE_AFTER_SECONDS": "10",
    "LTLNAV_MAX_ATTEMPTS": "3",
    "LTLNAV_RETRY_BACKOFF_SECONDS": "5",
}
"""Production-like timing, shortened where the defaults would only make the bench wait
(stale after 15 s instead of 60 s: the 90 s outage is still six times longer)."""

Scenario = Callable[[Cluster, Scale, Path], list[FaultRow]]

STATE = "state"
"""The folder, under a scenario's root, of the ``statedisk`` deployment's SQLite state file or
PostgreSQL tablespace."""

STATE_DISK_MB = 64
"""Size of the filesystem mounted there."""


def _dead_broker(cluster: Cluster) -> str:
    if cluster.kind == "embedded":
        return "sqla+sqlite:////proc/ltlnav-no-such-dir/broker.db"
    return f"redis://127.0.0.1:{free_port()}/0"


SCENARIOS: dict[str, Scenario] = {
    "child": lambda c, s, _: [scenarios.training_child_sigkill(c, s)],
    "phases": lambda c, s, _: scenarios.worker_sigkill_each_phase(c, s),
    # four budgets: the jobs still train when the database comes back
    "outage": lambda c, s, _: [scenarios.database_outage(c, replace(s, budget=4 * s.budget))],
    # the state's own filesystem full: the SQLite file's, or the PostgreSQL database's
    # tablespace (``deployment`` mounts it)
    "statedisk": lambda c, s, root: [
        scenarios.database_outage(c, replace(s, budget=4 * s.budget), full_disk=root / STATE)
    ],
    "broker": lambda c, s, _: scenarios.poison_mission(c, s, dead_broker=_dead_broker(c)),
    "enospc": lambda c, s, root: [scenarios.disk_full_at_checkpoint(c, s, root / "enospc")],
    "forced": lambda c, s, _: [
        scenarios.forced_reclaim(c, s, 300.0 if c.kind != "embedded" else 0.0)
    ],
    "truncated": lambda c, s, _: [scenarios.truncated_files(c, s)],
    "api": lambda c, s, _: [scenarios.api_restart(c, s)[0]],
}
"""Name -> scenario (``broker`` also runs the poison mission on the same worker)."""


@contextmanager
def deployment(
    kind: str, root: Path, redis_db: int, proxy: bool, state_disk: bool = False
) -> Iterator[Cluster]:
    """A fresh cluster of ``kind`` under ``root``; its processes killed and its PostgreSQL
    database dropped afterwards. With ``state_disk``, the SQLite state file, or the PostgreSQL
    database's tablespace, lives on a filesystem of its own (``STATE_DISK_MB``, under
    ``root / STATE``)."""
    with ExitStack() as stack:
        database_url = redis_url = None
        knobs = dict(KNOBS)
        tablespace = None
        if state_disk:
            problem = stack.enter_context(small_filesystem(root / STATE, STATE_DISK_MB))
            if kind == "redis-postgresql" and not problem:
                root.chmod(0o711)  # the server's user reaches the tablespace through it
                problem, tablespace = server_owns(root / STATE), root / STATE
            if problem:
                raise AssertionError(problem)
            if kind == "embedded":
                knobs["LTLNAV_DATABASE_URL"] = f"sqlite:///{root / STATE / 'ltlnav.db'}"
        if kind == "redis-postgresql":
            import redis

            database_url = stack.enter_context(
                postgres_database("ltlnav_bench_faults", tablespace=tablespace)
            )
            redis_url = f"redis://127.0.0.1:6379/{redis_db}"
            redis.Redis.from_url(redis_url).flushdb()
        cluster = make_cluster(kind, root, knobs, database_url, redis_url, proxy_database=proxy)
        try:
            yield cluster
        finally:
            cluster.stop()
            cluster.db.dispose()


def servers_answer() -> str:
    """Why Redis + PostgreSQL cannot be used ("" when both answer)."""
    try:
        import redis
        from sqlalchemy import create_engine, text

        redis.Redis.from_url("redis://127.0.0.1:6379/0", socket_connect_timeout=1).ping()
        engine = create_engine("postgresql+psycopg://postgres@127.0.0.1:5432/postgres")
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
        engine.dispose()
    except Exception as error:
        return f"{type(error).__name__}: {error}"
    return ""


HEADER = (
    f"{'deployment':<17} {'fault':<34} {'when':<44} {'outcome':<8} "
    f"{'lost/interval':>13} {'retrained':>9} {'dup':>3} {'recover':>8}  notes"
)


def format_row(row: FaultRow) -> str:
    lost = f"{row.lost}/{row.interval}" if row.before else "-"
    retrained = str(row.retrained) if row.before else "-"
    recover = f"{row.recover_seconds:.1f} s" if row.recover_seconds is not None else "-"
    notes = "; ".join(n for n in row.notes if not n.startswith("attempts before"))
    if row.tokens:
        after = {k: row.attempts.get(k) for k in row.tokens}
        notes = f"attempts {row.tokens} -> {after}" + (f"; {notes}" if notes else "")
    if row.status == "failed" and row.reason:
        notes = f"reason: {row.reason[:70]}" + (f"; {notes}" if notes else "")
    return (
        f"{row.deployment:<17} {row.fault[:34]:<34} {row.when[:44]:<44} {row.status:<8} "
        f"{lost:>13} {retrained:>9} {row.duplicates:>3} {recover:>8}  {notes}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--deployments", default="embedded,redis-postgresql")
    parser.add_argument("--only", default=",".join(SCENARIOS), help="scenario names")
    parser.add_argument("--budget", type=int, default=FULL.budget, help="steps per sub-task")
    parser.add_argument("--interval", type=int, default=FULL.interval, help="checkpoint steps")
    parser.add_argument("--outage", type=float, default=FULL.outage_seconds, help="seconds")
    parser.add_argument("--redis-db", type=int, default=10, help="Redis database (flushed)")
    args = parser.parse_args()
    scale = replace(FULL, budget=args.budget, interval=args.interval, outage_seconds=args.outage)
    kinds = [k for k in args.deployments.split(",") if k]
    names = [n for n in args.only.split(",") if n]
    print(f"ltlnav fault bench on {os.cpu_count()} cores, load {os.getloadavg()}", flush=True)
    print(f"scale {scale}\nknobs {KNOBS}", flush=True)
    rows: list[FaultRow] = []
    print(HEADER, flush=True)
    for kind in kinds:
        if kind == "redis-postgresql" and (why := servers_answer()):
            print(f"{kind}: skipped, the servers do not answer ({why})", flush=True)
            continue
        for name in names:
            started = time.monotonic()
            with tempfile.TemporaryDirectory(prefix=f"ltlnav-faults-{name}-") as folder:
                root = Path(folder)
                try:
                    with deployment(
                        kind,
                        root,
                        args.redis_db,
                        proxy=name == "outage",
                        state_disk=name == "statedisk",
                    ) as c:
                        found = SCENARIOS[name](c, scale, root)
                except AssertionError as error:
                    found = [FaultRow(kind, name, status="stuck", notes=[str(error)[:300]])]
            for row in found:
                rows.append(row)
                print(format_row(row), flush=True)
            print(f"# {kind} {name}: {time.monotonic() - started:.0f} s", flush=True)
    print("\n" + HEADER)
    for row in rows:
        print(format_row(row))
    print(f"load at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
