"""The task logic (``service.jobs.planning``, ``.training``, ``.assembly``) on a real SQLite
database and real tiny trainings, with the follow-up tasks recorded instead of sent."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import update

from service import repository
from service.db import Database, upgrade
from service.jobs.assembly import assemble_step
from service.jobs.common import forget_open_runs
from service.jobs.planning import plan_step
from service.jobs.progress import JobMonitor
from service.jobs.training import train_step
from service.models import Job, JobStatus, MissionStatus, utcnow
from service.settings import Settings
from tests.service.dispatch import Recorder
from tests.workers.missions import tiny_mission
from workers.bundle_reader import read_bundle
from workers.hooks import CurvePoint

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def settings(tmp_path: Path, sqlite_url: str) -> Settings:
    upgrade(sqlite_url)
    return Settings(
        data_dir=tmp_path,
        database_url=sqlite_url,
        heartbeat_seconds=0.2,
        stale_after_seconds=1.0,
    )


def submit(settings: Settings, document: dict[str, Any] | None = None) -> str:
    doc = document or tiny_mission().model_dump(mode="json")
    with Database(settings.database_url).session() as session:
        return repository.create_mission(session, doc["name"], doc, None).id


def load(settings: Settings, mission_id: str) -> Any:
    with Database(settings.database_url).session() as session:
        mission = repository.get_mission(session, mission_id)
        assert mission is not None
        jobs = repository.mission_jobs(session, mission_id)
        curves = {job.index: repository.learning_curve(session, job.id) for job in jobs}
        saved = {job.index: repository.latest_checkpoint(session, job.id) for job in jobs}
        return mission, jobs, curves, saved


def claimed_job(settings: Settings, worker: str) -> tuple[str, Database, Job]:
    """A planned default mission, its database and its job 0 claimed by ``worker``."""
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())
    db = Database(settings.database_url)
    with db.session() as session:
        job = repository.get_job(session, mission_id, 0)
        assert job is not None and repository.claim_job(session, job.id, worker) is not None
    return mission_id, db, job


def test_a_mission_runs_through_plan_train_assemble(settings: Settings) -> None:
    budget = 100  # half of TINY: the worker end-to-end tests train the whole of it
    document = tiny_mission(n_timesteps=budget, eval_freq=50, handover_rounds=0)
    mission_id = submit(settings, document.model_dump(mode="json"))
    sent = Recorder()
    assert plan_step(settings, mission_id, sent) == "planned"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.training
    assert sent.sent == [("training", mission_id, [job.index for job in jobs])]
    assert set(mission.plan) >= {"automaton_states", "pruned_states", "cost", "subtasks"}
    assert [s["index"] for s in mission.plan["subtasks"]] == [job.index for job in jobs]
    assert all(s["balls"] > 0 and s["length"] > 0 for s in mission.plan["subtasks"])
    folder = settings.artifact_dir / mission_id
    assert Path(mission.plan_image) == folder / "plan.png" and (folder / "plan.png").is_file()
    assert (folder / "plan.json").is_file()
    # a redelivered planning task changes nothing
    assert plan_step(settings, mission_id, sent) == "busy"
    assert len(sent.sent) == 1

    for job in jobs[:-1]:
        assert train_step(settings, mission_id, job.index, sent, in_chord=False) == "done"
    assert assemble_step(settings, mission_id, sent) == "waiting"
    last = jobs[-1].index
    assert train_step(settings, mission_id, last, sent, in_chord=False) == "done"
    assert sent.sent[-1] == ("assemble", mission_id)  # the last job outside a chord
    # a finished job is not trained again
    assert train_step(settings, mission_id, last, sent, in_chord=True) == "done"

    mission, jobs, curves, saved = load(settings, mission_id)
    for job in jobs:
        assert job.status == JobStatus.done and job.attempts == 1
        assert job.steps_done == budget and job.result["final"]["episodes"] == 2
        assert job.out_dir == str(folder / f"subtask_{job.index}")
        assert [p.steps for p in curves[job.index]] == [50, 100]
        assert saved[job.index] is not None and saved[job.index].steps == budget
    assert assemble_step(settings, mission_id, sent) == "done"
    assert assemble_step(settings, mission_id, sent) == "final"
    mission, *_ = load(settings, mission_id)
    assert mission.status == MissionStatus.done
    assert Path(mission.bundle_path) == folder / "bundle.zip" and (folder / "bundle.zip").is_file()
    assert mission.evaluation["episodes"] == 2
    manifest, _ = read_bundle(mission.bundle_path)
    shown = [(s["balls"], s["r_ball"]) for s in mission.plan["subtasks"]]
    assert shown == [(len(e.guide_centers), e.r_ball) for e in manifest.subtasks]


def test_the_plan_summary_shows_the_r_balls_the_agents_train_on(settings: Settings) -> None:
    doc = tiny_mission().model_dump(mode="json")
    doc["planner"]["r_ball"] = 0.5  # wider than the plan's 0.35 m clearance: narrowed to it
    mission_id = submit(settings, doc)
    assert plan_step(settings, mission_id, Recorder()) == "planned"
    mission, *_ = load(settings, mission_id)
    radii = [s["r_ball"] for s in mission.plan["subtasks"]]
    assert radii == pytest.approx([0.35] * len(radii))


def test_an_infeasible_mission_fails_with_the_planners_reason(settings: Settings) -> None:
    doc = tiny_mission().model_dump(mode="json")
    doc["task"] = "[]!obstacle && <>(a && b)"  # a and b are disjoint
    mission_id = submit(settings, doc)
    assert plan_step(settings, mission_id, Recorder()) == "infeasible"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.failed and jobs == []
    assert mission.reason and "unsatisfiable in this world" in mission.reason


def test_an_unexpected_error_fails_the_mission_with_a_reason(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())

    def broken(*_args: Any, **_kwargs: Any) -> Any:
        raise RuntimeError("boom")

    monkeypatch.setattr("workers.run.MissionRun.train", broken)
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "failed"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.failed
    assert mission.reason == "sub-task 0: RuntimeError: boom"
    assert jobs[0].status == JobStatus.failed and jobs[0].reason == mission.reason
    # the other jobs then do nothing
    assert train_step(settings, mission_id, 1, Recorder(), in_chord=True) == "final"


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_a_damaged_plan_file_is_planned_anew_to_the_same_plan(
    settings: Settings, damage: str
) -> None:
    mission_id = submit(settings, tiny_mission(n_timesteps=50).model_dump(mode="json"))
    plan_step(settings, mission_id, Recorder())
    stored = settings.artifact_dir / mission_id / "plan.json"
    good = json.loads(stored.read_text())
    if damage == "truncated":  # what a kill mid-write used to leave
        stored.write_text(stored.read_text()[: len(stored.read_text()) // 2])
    else:
        stored.write_text(json.dumps({**good, "plan": {**good["plan"], "subtasks": "garbage"}}))
    forget_open_runs()  # as in another worker process, which reads the plan anew
    with pytest.warns(UserWarning, match="planning anew"):
        assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "done"
    assert json.loads(stored.read_text())["plan"]["lasso"] == good["plan"]["lasso"]


def test_cancel_before_training_cancels_the_mission_and_its_queued_jobs(
    settings: Settings,
) -> None:
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())
    with Database(settings.database_url).session() as session:
        repository.request_cancel(session, mission_id)
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "cancelled"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.cancelled
    assert {job.status for job in jobs} == {JobStatus.cancelled}


def test_a_job_past_its_attempts_fails(settings: Settings) -> None:
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())
    with Database(settings.database_url).session() as session:
        job = repository.get_job(session, mission_id, 0)
        assert job is not None
        job.attempts = settings.max_attempts
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "failed"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.failed and "gave up after" in mission.reason
    assert jobs[0].status == JobStatus.failed


def test_cancel_during_training_stops_the_job_and_keeps_its_checkpoint(
    settings: Settings,
) -> None:
    budget = 5000
    doc = tiny_mission(n_timesteps=budget, eval_freq=100).model_dump(mode="json")
    mission_id = submit(settings, doc)
    plan_step(settings, mission_id, Recorder())
    outcome: list[str] = []
    thread = threading.Thread(
        target=lambda: outcome.append(train_step(settings, mission_id, 0, Recorder(), True))
    )
    thread.start()
    deadline = time.monotonic() + 60
    while load(settings, mission_id)[3][0] is None:  # until a checkpoint is recorded
        assert time.monotonic() < deadline and thread.is_alive()
        time.sleep(0.05)
    with Database(settings.database_url).session() as session:
        repository.request_cancel(session, mission_id)
    thread.join(timeout=30)
    assert outcome == ["cancelled"]
    mission, jobs, _, saved = load(settings, mission_id)
    assert mission.status == MissionStatus.cancelled
    assert jobs[0].status == JobStatus.cancelled and 0 < jobs[0].steps_done < budget
    assert {job.status for job in jobs[1:]} == {JobStatus.cancelled}
    assert Path(saved[0].path).is_file()


def repairing_mission(settings: Settings, **training: Any) -> tuple[str, Recorder]:
    """A mission whose 100 steps of training cannot make its target, trained, then assembled
    into its first round of hand-over repair."""
    doc = tiny_mission(n_timesteps=100, eval_freq=50, handover_steps=100, **training)
    mission_id = submit(settings, doc.model_dump(mode="json"))
    sent = Recorder()
    plan_step(settings, mission_id, sent)
    for job in load(settings, mission_id)[1]:
        assert train_step(settings, mission_id, job.index, sent, in_chord=True) == "done"
    assert assemble_step(settings, mission_id, sent) == "repairing"
    return mission_id, sent


def test_hand_over_repair_rounds_are_jobs_trained_in_parallel_then_judged(
    settings: Settings,
) -> None:
    mission_id, sent = repairing_mission(settings, handover_rounds=1)
    mission, jobs, _, _ = load(settings, mission_id)
    repairs = [job for job in jobs if job.repair_round == 1]
    indices = [job.index for job in repairs]
    assert repairs and sent.sent[-1] == ("training", mission_id, indices, 1)
    assert mission.status == MissionStatus.training and mission.repairs == []
    assert mission.reason.startswith("hand-over repair round 1: mission success ")
    assert mission.evaluation is not None  # the evaluation the round must beat
    for job in repairs:
        assert job.status == JobStatus.queued and job.budget == 100 and job.spec is not None
        assert job.spec["round"] == 1 and job.spec["starts"]
        assert job.out_dir == str(
            settings.artifact_dir / mission_id / f"subtask_{job.index}" / "handover_1"
        )
    assert assemble_step(settings, mission_id, sent) == "waiting"
    for index in indices:
        assert train_step(settings, mission_id, index, sent, True, repair_round=1) == "done"
    jobs = load(settings, mission_id)[1]
    for job in jobs:
        assert job.status == JobStatus.done and job.result["steps"] == 100
    assert assemble_step(settings, mission_id, sent) == "done"
    mission = load(settings, mission_id)[0]
    assert mission.status == MissionStatus.done and Path(mission.bundle_path).is_file()
    assert [(r["round"], r["subtasks"]) for r in mission.repairs] == [(1, indices)]
    record = json.loads((settings.artifact_dir / mission_id / "handover_repair.json").read_text())
    assert record["rounds"] == mission.repairs
    kept = mission.repairs[0]["kept"]
    assert {r["repairs"] for r in record["results"]} == ({0, 1} if kept else {0})


def test_a_cancel_stops_a_repair_round(settings: Settings) -> None:
    mission_id, _ = repairing_mission(settings)
    index = next(job.index for job in load(settings, mission_id)[1] if job.repair_round == 1)
    with Database(settings.database_url).session() as session:
        repository.request_cancel(session, mission_id)
    assert train_step(settings, mission_id, index, Recorder(), True, repair_round=1) == "cancelled"
    mission, jobs, _, _ = load(settings, mission_id)
    assert mission.status == MissionStatus.cancelled and mission.bundle_path is None
    assert {job.status for job in jobs if job.repair_round == 1} == {JobStatus.cancelled}


def test_a_job_handed_to_another_worker_stops_writing(settings: Settings) -> None:
    mission_id, db, job = claimed_job(settings, "old-worker")
    monitor = JobMonitor(db, mission_id, job.id, job.attempts, 0.01)
    monitor.progress(0, None, 200)
    time.sleep(0.02)
    monitor.check()
    assert not monitor.should_stop()
    with db.session() as session:  # the reconciler gave the job to another worker's attempt
        session.execute(
            update(Job)
            .where(Job.id == job.id)
            .values(
                worker="new-worker",
                attempts=Job.attempts + 1,
                heartbeat_at=utcnow() - timedelta(minutes=1),
            )
        )
    time.sleep(0.02)
    monitor.check()
    assert monitor.should_stop()
    monitor.progress(50, 0.5, 200)
    monitor.curve_point(CurvePoint(50, 1, 0.5))
    with db.session() as session:
        assert repository.learning_curve(session, job.id) == []
        stored = repository.get_job(session, mission_id, 0)
        assert (
            stored is not None
            and stored.steps_done == 0
            and stored.heartbeat_at is not None
            and stored.heartbeat_at < utcnow() - timedelta(seconds=30)
        )


def test_a_job_whose_training_ended_names_its_evaluation_instead_of_a_time_left(
    settings: Settings,
) -> None:
    mission_id, db, job = claimed_job(settings, "me")
    monitor = JobMonitor(db, mission_id, job.id, job.attempts, 0.01)
    monitor.progress(100, 0.5, 200)
    time.sleep(0.02)
    monitor.progress(150, 0.5, 200)
    running = load(settings, mission_id)[1][0]
    assert running.eta_seconds is not None and running.reason is None
    monitor.evaluating("picking the kept policy: 1 of 3")
    monitor.progress(150, 0.5, 200)  # the job's last progress, after its evaluations
    monitor.flush()
    evaluating = load(settings, mission_id)[1][0]
    assert evaluating.reason == "picking the kept policy: 1 of 3"
    assert evaluating.eta_seconds is None and evaluating.steps_done == 150
    with db.session() as session:
        said = [e.payload.get("evaluating") for e in repository.events_after(session, mission_id)]
    assert "picking the kept policy: 1 of 3" in said


class BrokerDown(Recorder):
    def training(self, mission_id: str, indices: Sequence[int], repair_round: int = 0) -> None:
        raise ConnectionError("broker down")


def test_a_broker_outage_after_planning_loses_nothing(settings: Settings) -> None:
    mission_id = submit(settings)
    assert plan_step(settings, mission_id, BrokerDown()) == "planned"
    mission, jobs, _, _ = load(settings, mission_id)
    # the state is committed: the reconciler sends the queued jobs once the broker is back
    assert mission.status == MissionStatus.training and mission.reason is None
    assert {job.status for job in jobs} == {JobStatus.queued}


def test_failure_reasons_name_the_problem() -> None:
    from celery.exceptions import SoftTimeLimitExceeded

    from planner.errors import PlanningError
    from service.jobs.common import describe

    assert describe(PlanningError("no path")) == "no path"
    assert describe(KeyError("x")) == "KeyError: 'x'"
    assert "time limit" in describe(SoftTimeLimitExceeded())


def test_a_redelivered_task_leaves_a_running_job_alone(settings: Settings) -> None:
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())
    with Database(settings.database_url).session() as session:
        job = repository.get_job(session, mission_id, 0)
        assert job is not None
        assert repository.claim_job(session, job.id, "elsewhere") is not None
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "busy"
    _, jobs, _, _ = load(settings, mission_id)
    assert jobs[0].status == JobStatus.running and jobs[0].worker == "elsewhere"
    assert jobs[0].attempts == 1


def test_a_database_blip_delays_progress_writes_but_loses_none(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sqlalchemy.exc import OperationalError

    mission_id, db, job = claimed_job(settings, "me")
    path = Path(job.out_dir) / "checkpoints" / "model_100_steps.zip"
    monitor = JobMonitor(db, mission_id, job.id, job.attempts, 0.01)
    real = repository.record_progress, repository.record_checkpoint

    def down(*_args: Any, **_kwargs: Any) -> None:
        raise OperationalError("UPDATE jobs", {}, Exception("connection lost"))

    monkeypatch.setattr(repository, "record_progress", down)
    monkeypatch.setattr(repository, "record_checkpoint", down)
    monitor.checkpoint(100, path)  # logged, not raised: training goes on
    monitor.progress(100, None, 200)
    assert load(settings, mission_id)[3][0] is None
    monkeypatch.setattr(repository, "record_progress", real[0])
    monkeypatch.setattr(repository, "record_checkpoint", real[1])
    time.sleep(0.02)
    monitor.progress(150, None, 200)
    _, jobs, _, saved = load(settings, mission_id)
    assert saved[0] is not None and saved[0].steps == 100 and jobs[0].steps_done == 150


def test_a_residual_jobs_start_check_is_the_first_point_of_its_curve(settings: Settings) -> None:
    doc = tiny_mission(n_timesteps=100, eval_freq=50, env={"guide_feedforward": 1.0})
    mission_id = submit(settings, doc.model_dump(mode="json"))
    plan_step(settings, mission_id, Recorder())
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "done"
    _, jobs, curves, _ = load(settings, mission_id)
    points = [(p.steps, p.success_rate) for p in curves[0]]
    assert points == [tuple(p) for p in jobs[0].result["curve"]]
    assert points[0][0] == 0 and [s for s, _ in points[1:]] in ([], [50, 100])


def test_a_restarted_job_keeps_one_start_point(settings: Settings) -> None:
    mission_id, db, job = claimed_job(settings, "me")
    start = CurvePoint(0, 4, 0.25)

    def curve() -> list[tuple[int, int, float]]:
        points = load(settings, mission_id)[2][0]
        return [(p.steps, p.episodes, p.success_rate) for p in points]

    def run(resumed: int, *points: CurvePoint) -> None:
        monitor = JobMonitor(db, mission_id, job.id, job.attempts, 0.01)
        monitor.resumed(resumed)
        for point in points:
            monitor.curve_point(point)
        monitor.progress(resumed, 0.25, 200)

    run(0, start)
    assert curve() == [(0, 4, 0.25)]
    run(0, start, CurvePoint(50, 1, 1.0))  # a fresh start again: its own points only
    assert curve() == [(0, 4, 0.25), (50, 1, 1.0)]
    run(0, start)
    assert curve() == [(0, 4, 0.25)]
    run(100)  # resumed: the points before the checkpoint stay
    assert curve() == [(0, 4, 0.25)]


def test_one_walk_through_the_steps_parses_the_mission_and_plans_once(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Planning, every training job and the assembly in one process: the document is
    validated once, the formula parsed once, the plan made once and never read back."""
    import planner.ltl.parser
    import planner.plan
    import planner.serialize
    import workers.run
    from planner.ltl.formula import parse

    calls: dict[str, int] = {}

    def counted(module: Any, name: str) -> None:
        real = getattr(module, name)

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            calls[name] = calls.get(name, 0) + 1
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, wrapper)

    counted(workers.run, "parse_mission")
    counted(planner.plan, "plan_mission")
    counted(workers.run, "plan_from_dict")
    counted(planner.serialize, "plan_from_dict")
    counted(planner.ltl.parser.Parser, "parse")
    forget_open_runs()
    parse.cache_clear()
    document = tiny_mission(n_timesteps=50, eval_freq=50, handover_rounds=0)
    mission_id = submit(settings, document.model_dump(mode="json"))
    sent = Recorder()
    assert plan_step(settings, mission_id, sent) == "planned"
    for job in load(settings, mission_id)[1]:
        assert train_step(settings, mission_id, job.index, sent, in_chord=True) == "done"
    assert assemble_step(settings, mission_id, sent) == "done"
    assert calls == {"parse_mission": 1, "plan_mission": 1, "parse": 1}
