"""The assembly step of a mission, once every job of its latest round is done.

It evaluates the whole mission (the concatenated policy, judged by the automaton). While the
mission is below ``training.mission_target`` it runs rounds of hand-over repair
(``workers.handover_repair``) as jobs of their own: the round's jobs become job rows
(``repair_round`` r, the job's starts in ``spec``) trained in parallel like the first ones,
with progress, curves and cancel, and the assembly that follows them judges the round (kept
only if the mission improved). Then it writes ``bundle.zip`` and the mission is done. What
was judged is stored on the mission (``repairs``, and the evaluation of the results kept), so
any worker can take the next step.

The step claims the mission with a compare-and-set (training -> evaluating) that counts the
attempt: an assembly that kept dying fails the mission after ``max_attempts`` with a reason
that says so (each repair round's assembly counts anew); a transient error puts the mission
back after a backoff.
"""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy.orm import Session

from service import repository
from service.db import Database
from service.jobs.common import (
    Dispatch,
    cancel_mission,
    database_for,
    fail_mission,
    failing,
    gave_up,
    open_run,
    retry_step,
    send,
)
from service.jobs.progress import mission_heartbeat
from service.models import Job, JobStatus, MissionStatus
from service.settings import Settings
from workers.evaluation import MissionEvaluation
from workers.handover_repair import RepairRound, kept_results
from workers.run import MissionRun
from workers.train_result import TrainResult


def assemble_step(settings: Settings, mission_id: str, dispatch: Dispatch) -> str:
    """Evaluate, judge the last repair round, start the next one or write the bundle.
    Returns what happened (``done``, ``repairing``, ``waiting``, ``busy``, ``cancelled``,
    ...)."""
    db = database_for(settings)
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        if mission is None:
            return "missing"
        if mission.status in repository.FINAL_STATES:
            return "final"
        cancelled, last = mission.cancel_requested, mission.reason
        jobs = repository.mission_jobs(session, mission_id)
        if not cancelled and (not jobs or any(j.status != JobStatus.done for j in jobs)):
            return "waiting"
        claimed = None
        if not cancelled:
            claimed = repository.claim_step(
                session,
                mission_id,
                MissionStatus.training,
                MissionStatus.evaluating,
                "assembly_attempts",
            )
        document = mission.document
        rounds = _results_by_round(jobs)
        judged = [RepairRound.from_json(doc) for doc in mission.repairs or []]
        interim = mission.evaluation
    if cancelled:
        cancel_mission(db, mission_id)
        return "cancelled"
    if claimed is None:
        return "busy"
    attempt = claimed
    if attempt > settings.max_attempts:
        fail_mission(db, mission_id, gave_up("assembly", attempt - 1, last))
        return "failed"

    def retry(error: BaseException) -> bool:
        back = MissionStatus.evaluating, MissionStatus.training
        return retry_step(settings, mission_id, back, attempt, error, dispatch.assemble)

    with (
        failing(db, mission_id, "assembly", retry=retry),
        mission_heartbeat(db, mission_id, settings.heartbeat_seconds),
    ):
        run = open_run(settings, mission_id, document)
        results = kept_results(rounds, judged)
        pending = rounds[len(judged) + 1] if len(rounds) > len(judged) + 1 else None
        if pending is not None:
            if interim is None:
                raise RuntimeError("a repair round finished but the evaluation before it is lost")
            before = MissionEvaluation(**interim)
            seconds = max(r.seconds for r in pending)
            results, evaluation, record = run.judge(
                len(judged) + 1, results, before, pending, seconds
            )
            judged.append(record)
            go_on = record.kept
        else:
            evaluation = run.evaluate(results)
            go_on = True
        step = (mission_id, attempt)
        if go_on and run.needs_repair(evaluation, len(judged)):
            outcome = _start_round(db, run, step, results, evaluation, judged, dispatch)
            if outcome is not None:
                return outcome
        out = run.finish(results, evaluation, judged)
        reported = out.evaluation
        with db.session() as session:
            if not _holds(session, step):
                return "lost"
            repository.set_result(session, mission_id, reported.to_json(), str(out.bundle))
            repository.set_repairs(
                session, mission_id, reported.to_json(), [r.to_json() for r in judged]
            )
            repository.record_evaluation(
                session,
                mission_id,
                None,
                steps=sum(r.steps for r in out.results),
                episodes=reported.episodes,
                success_rate=reported.success_rate,
            )
            repository.set_status(session, mission_id, MissionStatus.done)
        return "done"
    with db.session() as session:  # the guard failed the mission, or put it back for later
        ended = repository.get_mission(session, mission_id)
        return (
            "retrying" if ended is not None and ended.status == MissionStatus.training else "failed"
        )


def _holds(session: Session, step: tuple[str, int]) -> bool:
    """Whether this assembly attempt (``(mission id, attempt)``) still owns the mission."""
    mission_id, attempt = step
    evaluating = MissionStatus.evaluating
    return repository.holds_step(session, mission_id, evaluating, "assembly_attempts", attempt)


def _start_round(
    db: Database,
    run: MissionRun,
    step: tuple[str, int],
    results: list[TrainResult],
    evaluation: MissionEvaluation,
    judged: list[RepairRound],
    dispatch: Dispatch,
) -> str | None:
    """Create the next repair round's job rows and send them (None: no job to run, so the
    mission is assembled as it stands)."""
    round_ = len(judged) + 1
    jobs = run.repair_jobs(results, round_)
    if not jobs:
        return None
    rows = [
        repository.NewJob(
            index=job.subtask,
            budget=job.training.n_timesteps,
            out_dir=str(run.job_folder(job)),
            repair_round=round_,
            spec=job.to_json(),
        )
        for job in jobs
    ]
    subtasks = ", ".join(str(job.subtask) for job in jobs)
    news = (
        f"hand-over repair round {round_}: mission success "
        f"{100 * evaluation.success_rate:.0f} %, below its target; sub-task(s) {subtasks} "
        "train on from the poses the mission's rollouts handed them over in"
    )
    mission_id = step[0]
    with db.session() as session:
        if not _holds(session, step):
            return "lost"
        repository.create_jobs(session, mission_id, rows, repair_round=round_)
        repository.set_repairs(
            session, mission_id, evaluation.to_json(), [r.to_json() for r in judged]
        )
        try:
            repository.set_status(session, mission_id, MissionStatus.training, news)
        except repository.TransitionError:  # cancelled meanwhile
            repository.cancel_queued_jobs(session, mission_id)
            return "final"
    indices = [job.subtask for job in jobs]
    send(lambda: dispatch.training(mission_id, indices, round_), mission_id)
    return "repairing"


def _results_by_round(jobs: Sequence[Job]) -> list[list[TrainResult]]:
    """The finished jobs' results, round by round (round 0 first), each by sub-task."""
    rounds: dict[int, list[TrainResult]] = {}
    for job in sorted(jobs, key=lambda j: (j.repair_round, j.index)):
        rounds.setdefault(job.repair_round, []).append(TrainResult.from_json(job.result or {}))
    return [rounds[r] for r in sorted(rounds)]
