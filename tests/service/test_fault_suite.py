"""The fault suite: real worker processes (``tests.service.fault_hooks.worker``), real SIGKILL,
outages of the database and the broker, a full disk, a second runner on a live job, truncated
files, an API restart under pollers and a poison mission, on the embedded defaults and on
Redis + PostgreSQL (started when absent, else skipped with the reason). Each fault's mission
completes (or fails with the right reason), loses at most one checkpoint interval of training,
writes nothing twice, and the other missions on the same workers complete.

The scenarios live in ``tests.service.fault_hooks.scenarios``; ``bench/faults.py`` runs them at
full scale. Settings come from ``FAST`` (heartbeat 0.3 s, stale after 3 s, 3 attempts).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import text, update

from service import repository
from service.db import Database, upgrade
from service.jobs.common import failing
from service.models import Base, Job, JobStatus, MissionStatus
from tests.service.fault_hooks import scenarios
from tests.service.fault_hooks.cluster import (
    FAST,
    Cluster,
    ensure_redis,
    free_port,
    make_cluster,
    postgres_database,
    server_owns,
    small_filesystem,
)
from tests.service.fault_hooks.scenarios import TEST, FaultRow
from tests.workers.missions import tiny_mission

REDIS_DB = 12
"""The Redis database of this suite (flushed before and after; the worker e2e tests use 13)."""

pytestmark = pytest.mark.timeout(300)


def _redis_url() -> str:
    """The suite's Redis database, flushed (Redis started when absent, else the test skips)."""
    import redis

    url = f"redis://127.0.0.1:6379/{REDIS_DB}"
    problem = ensure_redis(url)
    if problem:
        pytest.skip(problem)
    redis.Redis.from_url(url).flushdb()
    return url


def _cluster(request: pytest.FixtureRequest, root: Path, proxy: bool = False) -> Iterator[Cluster]:
    kind = request.param
    database_url = redis_url = None
    if kind == "redis-postgresql":
        database_url = request.getfixturevalue("migrated_postgres")
        redis_url = _redis_url()
    cluster = make_cluster(kind, root, FAST, database_url, redis_url, proxy_database=proxy)
    try:
        yield cluster
    finally:
        cluster.stop()
        if kind == "redis-postgresql":
            import redis

            assert redis_url is not None
            redis.Redis.from_url(redis_url).flushdb()
            tables = ", ".join(t.name for t in Base.metadata.sorted_tables)
            with cluster.db.engine.begin() as connection:
                connection.execute(text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))
            cluster.db.dispose()


@pytest.fixture(params=["embedded", "redis-postgresql"])
def cluster(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Cluster]:
    """A deployment with no process started yet; every process killed after the test."""
    yield from _cluster(request, tmp_path)


@pytest.fixture(params=["embedded", "redis-postgresql"])
def proxied(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Cluster]:
    """As ``cluster``, its workers reaching PostgreSQL through a pausable proxy."""
    yield from _cluster(request, tmp_path, proxy=True)


def assert_recovered(row: FaultRow, cluster: Cluster) -> None:
    """The mission completed, lost at most one checkpoint interval, wrote nothing twice."""
    assert row.status == "done", (row, cluster.tail())
    assert row.duplicates == 0, row
    assert row.resumed.keys() == row.before.keys(), row
    assert 0 <= row.lost <= row.interval, row


def dead_broker(cluster: Cluster) -> str:
    """A broker URL nothing answers at: a closed port, or a file that cannot be opened."""
    if cluster.kind == "embedded":
        return "sqla+sqlite:////proc/ltlnav-no-such-dir/broker.db"
    return f"redis://127.0.0.1:{free_port()}/{REDIS_DB}"


embedded_only = pytest.mark.parametrize("cluster", ["embedded"], indirect=True)
server_only = pytest.mark.parametrize("cluster", ["redis-postgresql"], indirect=True)


@embedded_only
@pytest.mark.slow
def test_sigkill_of_a_training_child(cluster: Cluster) -> None:
    """The prefork child training a job dies: the job resumes from its checkpoint."""
    row = scenarios.training_child_sigkill(cluster, TEST)
    assert_recovered(row, cluster)
    (index,) = row.before
    assert row.attempts[index] == 2, row  # the killed attempt and the one that finished
    assert all(n == 1 for k, n in row.attempts.items() if k != index), row


@server_only
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sigkill_of_the_worker_in_planning_training_and_assembly(cluster: Cluster) -> None:
    """One mission, its worker killed in each of its three steps and replaced each time (on
    Redis + PostgreSQL: the embedded defaults' worker SIGKILL mid-training is
    ``test_worker_e2e``'s, all three phases are ``bench/faults.py``'s)."""
    planning, training, assembly = scenarios.worker_sigkill_each_phase(cluster, TEST)
    assert_recovered(training, cluster)
    assert training.before and all(training.attempts[k] == 2 for k in training.before), training
    mission_id = cluster_mission(cluster)
    found = cluster.snapshot(mission_id)
    assert found.mission.plan_attempts == 2, found.mission  # the killed planning, then one
    assert found.mission.bundle_path is not None and Path(found.mission.bundle_path).is_file()
    moves = [(p["status"], p["reason"]) for k, p in cluster.events(mission_id) if k == "status"]
    assert moves.count(("planning", None)) == 2, moves
    assert moves.count(("evaluating", None)) == 2, moves  # the killed assembly, then one
    assert ("queued", "planning stalled: its worker stopped") in moves, moves
    assert ("training", "evaluating stalled: its worker stopped") in moves, moves
    for row in (planning, assembly):
        assert row.status == "done" and row.duplicates == 0, row
        assert row.recover_seconds is not None


def cluster_mission(cluster: Cluster) -> str:
    """The one mission a scenario submitted."""
    from sqlalchemy import select

    from service.models import Mission

    with cluster.db.session() as session:
        (mission_id,) = session.scalars(select(Mission.id))
        return mission_id


@pytest.mark.slow
def test_database_outage_mid_training(proxied: Cluster) -> None:
    """The database unreachable for 15 s mid-training: on PostgreSQL (a paused proxy) the
    jobs keep training through it and keep their attempt; on SQLite (an exclusive lock held by
    another process) progress writes wait for the lock, and a job whose heartbeat went stale
    meanwhile is reclaimed and resumes from its checkpoint. Either way the mission completes,
    nothing is written twice."""
    # on PostgreSQL a budget that outlasts the outage even on an idle machine (up to 100 steps
    # a second); SQLite's lock stalls training anyway
    budget = 2500 if proxied.kind == "redis-postgresql" else 600
    row = scenarios.database_outage(proxied, replace(TEST, budget=budget))
    assert_recovered(row, proxied)
    if proxied.kind == "redis-postgresql":
        kept = [k for k in row.tokens if row.attempts[k] == row.tokens[k]]
        reused = [k for k in row.tokens if f"sub-task {k}: result reused" in row.notes]
        # not reclaimed while training on: the same attempts finished (a job that ended during
        # the outage could not record it; its next attempt took the stored result without
        # training again). On a fast machine every job may end during the outage.
        assert sorted(kept + reused) == sorted(row.tokens), row
        assert row.notes[0] != "0 checkpoint files written during the outage", row


OUTLASTING = {**FAST, "LTLNAV_MAX_ATTEMPTS": "8"}
"""``FAST`` with attempts that outlast a 15 s outage, as the defaults' do (5 attempts, 5 s
doubling: 75 s). With 3 an assembly that lands in the outage gives up within about 10 s: the
PostgreSQL test passed only while the assembly's writes fitted the pages already allocated."""


def assert_survives_a_full_disk(cluster: Cluster, disk: Path, refusal: str) -> None:
    """``disk`` (the state's own filesystem) full for 15 s mid-training, and on until a write
    of the workers was refused with ``refusal`` in the logs: the mission recovered (then the
    cluster stops)."""
    try:
        scale = replace(TEST, budget=600)
        row = scenarios.database_outage(cluster, scale, full_disk=disk, felt=refusal)
        assert_recovered(row, cluster)
        assert row.facts["filled bytes"] > 0, row
        assert refusal in cluster.tail(10**6), cluster.tail()
    finally:
        cluster.stop()
        cluster.db.dispose()


@pytest.mark.slow
def test_a_full_disk_under_the_sqlite_state_mid_training(tmp_path: Path) -> None:
    """The filesystem of the SQLite state file full for 15 s mid-training (a tmpfs of its own,
    filled up): every write of the workers is refused meanwhile ("database or disk is full"),
    not merely delayed as by a lock. The mission completes and nothing is written twice."""
    state = tmp_path / "state"
    with small_filesystem(state, megabytes=32) as problem:
        if problem:
            pytest.skip(problem)
        knobs = {**FAST, "LTLNAV_DATABASE_URL": f"sqlite:///{state / 'ltlnav.db'}"}
        cluster = make_cluster("embedded", tmp_path, knobs)
        assert_survives_a_full_disk(cluster, state, "database or disk is full")


@pytest.mark.slow
def test_a_full_disk_under_the_postgresql_tablespace_mid_training(
    tmp_path: Path, postgres_url: str
) -> None:
    """The mission database's files on a filesystem of their own (a tablespace on a 32 MB
    tmpfs) full for 15 s mid-training: the server refuses every write that needs space
    ("could not extend file ...: No space left on device"), while its log and other databases
    carry on. The mission completes and nothing is written twice."""
    # not under tmp_path: the server's user must be able to reach it (pytest's folders are 0700)
    files = Path(tempfile.mkdtemp(prefix="ltlnav-tablespace-"))
    try:
        with small_filesystem(files, megabytes=32) as problem:
            if problem or (problem := server_owns(files)):
                pytest.skip(problem)
            with postgres_database("ltlnav_test_full", tablespace=files) as database_url:
                cluster = make_cluster(
                    "redis-postgresql", tmp_path, OUTLASTING, database_url, _redis_url()
                )
                assert_survives_a_full_disk(cluster, files, "No space left on device")
    finally:
        files.rmdir()


@pytest.mark.slow
def test_poison_mission_fails_and_a_mission_sent_while_the_broker_was_down_completes(
    cluster: Cluster,
) -> None:
    """A planning that kills its process every time fails after ``LTLNAV_MAX_ATTEMPTS`` with
    the reason, in the mission and its event stream; a mission submitted meanwhile while the
    broker was unreachable is sent by the reconciler and completes on the same worker."""
    poison, good = scenarios.poison_mission(cluster, TEST, dead_broker=dead_broker(cluster))
    attempts = int(FAST["LTLNAV_MAX_ATTEMPTS"])
    assert poison.status == "failed", (poison, cluster.tail())
    assert poison.reason is not None
    assert poison.reason.startswith(f"planning: gave up after {attempts} attempts"), poison
    assert "worker process ended" in poison.reason
    assert poison.notes[-1] == f"event: {poison.reason}", poison
    assert good.status == "done" and good.duplicates == 0, (good, cluster.tail())
    assert good.when.startswith("submit: ") and good.when != "submit: sent", good
    assert good.notes[0] == "status after submit: queued", good
    assert all(n == 1 for n in good.attempts.values()), good


@server_only
@pytest.mark.slow
def test_disk_full_at_a_checkpoint_is_retried_after_backoff(
    cluster: Cluster, tmp_path: Path
) -> None:
    """``ENOSPC`` writing a checkpoint: the job goes back to queued, waits its backoff and
    completes from its last checkpoint."""
    row = scenarios.disk_full_at_checkpoint(cluster, TEST, tmp_path / "enospc")
    assert_recovered(row, cluster)
    (index,) = row.before
    assert row.attempts[index] == 2, row
    events = [p for k, p in cluster.events(cluster_mission(cluster)) if k == "job"]
    retry = [p for p in events if "No space left" in (p.get("reason") or "")]
    assert len(retry) == 1 and "trying again in 1 s" in retry[0]["reason"], events


@server_only
@pytest.mark.slow
def test_a_skewed_worker_reclaims_no_live_job_and_a_fenced_runner_writes_nothing(
    cluster: Cluster,
) -> None:
    """Two workers, one with its clock 5 minutes ahead: staleness is judged on the database
    clock, so no live job is reclaimed. A job's attempt forced on while its runner still runs:
    that runner writes no row and no file more; the job is then reclaimed and completes."""
    row = scenarios.forced_reclaim(cluster, TEST, skew_seconds=300)
    assert_recovered(row, cluster)
    assert row.notes[0] == "stale attempt wrote 0 rows, 0 files", row
    (index,) = row.before
    forced = row.tokens[index] + 1
    assert row.attempts[index] == forced + 1, row  # the forced token, then one reclaim
    assert all(n == 1 for k, n in row.attempts.items() if k != index), row
    assert row.notes[-1] == "1 stale-heartbeat reclaims", row  # only the forced job's


@embedded_only
@pytest.mark.slow
def test_truncated_plan_result_and_checkpoint(cluster: Cluster) -> None:
    """A killed worker's files cut short: the plan is made again, the result written anew and
    the damaged checkpoint skipped for the one before it."""
    row = scenarios.truncated_files(cluster, TEST)
    assert row.status == "done" and row.duplicates == 0, (row, cluster.tail())
    assert any(n.startswith("plan.json valid again; result.json steps 300") for n in row.notes)
    index, damaged = row.facts["index"], row.facts["damaged"]
    # the newest checkpoint was damaged: the job resumed from the one before it
    assert row.resumed[index] == damaged - TEST.interval, row
    assert row.lost <= 2 * row.interval, row


@embedded_only
def test_api_restart_under_fifty_pollers(cluster: Cluster) -> None:
    """The API SIGKILLed and started again while 50 clients poll a mission: no 5xx ever, no
    failure outside the gap, and every poller is served again after the restart."""
    row, polls = scenarios.api_restart(cluster, replace(TEST, poll_seconds=20))
    assert polls.back_at is not None, (row, cluster.tail())
    assert not [s for *_, s in polls.seen if s >= 500], row
    failures = [(k, sent, t, s) for k, sent, t, s in polls.seen if s != 200]
    # only requests of the gap fail, however late their failure comes back (a request sent as
    # the API came back may still be refused; one queued before it served can time out)
    outside = [f for f in failures if not (polls.kill_at <= f[2] and f[1] <= polls.back_at + 1.0)]
    assert failures and not outside, (row, polls.back_at, outside[:10])
    served_after = {k for k, _, t, s in polls.seen if s == 200 and t >= polls.back_at}
    assert served_after == set(range(TEST.pollers)), row


def test_reconciler_trusts_no_stale_heartbeat_right_after_a_database_outage() -> None:
    """``OutageWatch``: reclaims resume ``grace`` seconds after the database answered again."""
    from service.jobs.reconcile import OutageWatch

    watch = OutageWatch(grace=0.2)
    assert watch.may_reclaim()  # no outage seen
    watch.failed()
    assert not watch.may_reclaim()  # the first pass after the outage
    time.sleep(0.1)
    assert not watch.may_reclaim()
    watch.failed()  # down again: the grace starts over
    time.sleep(0.15)
    assert not watch.may_reclaim()
    time.sleep(0.25)
    assert watch.may_reclaim()


def test_a_checkpoint_cut_in_half_is_skipped_for_the_one_before(tmp_path: Path) -> None:
    """A model .zip cut in half (a kill or a full disk mid-copy outside ``save_with``) opens
    as a zip without its data, which SB3 reports with an AssertionError: the job resumes from
    the checkpoint before it instead of failing the mission."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from workers.agents import load_agent
    from workers.run import MissionRun
    from workers.training import subtask_env

    mission = tiny_mission(n_timesteps=100, eval_freq=50, checkpoint_freq=50)
    run = MissionRun.open(mission, tmp_path / "mission")
    job = run.jobs()[0]
    run.train(job)
    folder = run.job_folder(job) / "checkpoints"
    newest = folder / "model_100_steps.zip"
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])
    env = DummyVecEnv([lambda: subtask_env(run.mission, run.plan, job.training, job.subtask)])
    with pytest.warns(UserWarning, match="model_100_steps.zip"):
        model, steps = load_agent(job.training, env, folder, job.seed)
    assert steps == 50 and model.num_timesteps == 50
    env.close()


def test_a_stale_attempt_that_fails_records_nothing(sqlite_url: str) -> None:
    """An attempt whose job was claimed again meanwhile, and which then fails, neither fails
    the job nor the mission: the job's current attempt decides."""
    upgrade(sqlite_url)
    db = Database(sqlite_url)
    document = tiny_mission().model_dump(mode="json")
    with db.session() as session:
        mission_id = repository.create_mission(session, document["name"], document, None).id
        new = repository.NewJob(index=0, budget=100, out_dir="unused")
        (job,) = repository.create_jobs(session, mission_id, [new])
        job_id = job.id
    with db.session() as session:
        claimed = repository.claim_job(session, job_id, "first")
        assert claimed is not None and claimed.attempts == 1
    with db.session() as session:  # a second runner's claim: the token moves on
        session.execute(update(Job).where(Job.id == job_id).values(attempts=2))
    with failing(db, mission_id, "sub-task 0", job=(job_id, 1)):
        raise RuntimeError("the stale attempt broke")
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        stored = repository.get_job(session, mission_id, 0)
        assert mission is not None and stored is not None
        assert mission.status == MissionStatus.queued and mission.reason is None
        assert stored.status == JobStatus.running and stored.reason is None
    with failing(db, mission_id, "sub-task 0", job=(job_id, 2)):  # the holder's error counts
        raise RuntimeError("the current attempt broke")
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        assert mission is not None and mission.status == MissionStatus.failed
        assert mission.reason == "sub-task 0: RuntimeError: the current attempt broke"
    db.dispose()
