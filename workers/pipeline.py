"""The local pipeline behind ``ltlnav train``: plan, train every sub-task in K processes,
evaluate the whole mission, write ``bundle.zip``.

Re-running it on the same output folder resumes: the plan is reused when the mission is
unchanged (``plan.json``), each sub-task's job resumes from its checkpoints or returns its
stored result (``subtask_<k>/``).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import queue
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.errors import PlanningError
from planner.plan import MissionPlan, plan_mission, verify_plan
from planner.serialize import plan_from_dict, plan_to_dict
from workers.evaluation import MissionEnv, MissionEvaluation, rollout_mission, stage_policies
from workers.handover_repair import RepairRound, RunJobs, repair_handovers
from workers.mission import MissionSpec
from workers.training import ALGORITHMS, TrainingError, TrainResult, train_subtask
from workers.training_spec import SubtaskJob

EVALUATION_SEED = 7
"""Offset of the reported mission rollouts' seed from ``training.seed``."""

REPAIR_RECORD = "handover_repair.json"
"""What ``finish`` did: the repair rounds, the sub-task results kept and the mission's
evaluation (the bundle holds them too)."""

PipelineProgress = Callable[[int, int, float | None, int], None]
"""``on_progress(subtask, steps, success_rate, total)``, called in the parent process."""


@dataclass
class PipelineResult:
    """What ``run_pipeline`` produced."""

    bundle: Path
    plan: MissionPlan
    results: list[TrainResult]
    evaluation: MissionEvaluation
    repairs: list[RepairRound] = field(default_factory=list)
    """The rounds of hand-over repair run (``workers.handover_repair``)."""


def plan_for(mission: MissionSpec, out_dir: Path) -> MissionPlan:
    """The mission's plan: reused from ``out_dir/plan.json`` when made for the same mission,
    else planned, verified and stored there."""
    stored = out_dir / "plan.json"
    document = mission.model_dump(mode="json")
    planning = {k: v for k, v in document.items() if k != "training"}
    if stored.is_file():
        saved = json.loads(stored.read_text())
        if saved.get("mission") == planning:
            return plan_from_dict(saved["plan"])
    world = mission.build_world()
    radius = mission.robot.radius
    plan = plan_mission(world, mission.task, mission.robot.position(), radius, mission.planner)
    problems = verify_plan(plan, world, radius)
    if problems:
        raise PlanningError("the plan failed its own check: " + "; ".join(problems))
    out_dir.mkdir(parents=True, exist_ok=True)
    stored.write_text(json.dumps({"mission": planning, "plan": plan_to_dict(plan)}))
    return plan


def _run_job(job: SubtaskJob, out_dir: str, updates: Any, offset: int = 0) -> TrainResult:
    """One training job in a worker process; progress goes to the ``updates`` queue, its steps
    counted from ``offset`` (a repair continues the sub-task's bar)."""

    def report(steps: int, rate: float | None, total: int) -> None:
        updates.put((job.subtask, offset + steps, rate, offset + total))

    return train_subtask(job, out_dir, on_progress=report)


def run_pipeline(
    mission: MissionSpec,
    out_dir: str | Path,
    jobs: int | None = None,
    on_progress: PipelineProgress | None = None,
) -> PipelineResult:
    """Plan ``mission``, train its sub-tasks (``jobs`` processes, default the CPU count), roll
    out the concatenated policy, repair hand-overs while the mission is below its target
    (``workers.handover_repair``) and write ``out_dir/bundle.zip``. The training section
    (budget, seed, ...) is the mission's own: override it on the spec before calling."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if mission.training.reward.mode == "g-rrt":
        raise TrainingError(
            "reward mode g-rrt trains one agent for the whole lasso; the bundle pipeline "
            "concatenates one agent per sub-task: use rrt, rrt-paper, ned or tl"
        )
    plan = plan_for(mission, out)
    specs = subtask_jobs(mission, plan)
    if on_progress is not None:  # every sub-task shows up at once, in order
        for spec in specs:
            on_progress(spec.subtask, 0, None, spec.training.n_timesteps)
    workers = max(1, min(jobs or os.cpu_count() or 1, len(specs)))
    # forkserver: workers fork from a clean single-threaded server (this process runs a relay
    # thread), which imports torch and stable-baselines3 once for all of them.
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["workers.training"])
    with context.Manager() as manager:
        updates = manager.Queue()
        done = threading.Event()
        relay = threading.Thread(target=_relay, args=(updates, done, on_progress), daemon=True)
        relay.start()
        try:
            with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:

                def run(batch: list[tuple[SubtaskJob, Path, int]]) -> list[TrainResult]:
                    futures = [
                        pool.submit(_run_job, job, str(folder), updates, offset)
                        for job, folder, offset in batch
                    ]
                    return [f.result() for f in futures]

                results = run([(job, out / f"subtask_{job.subtask}", 0) for job in specs])
                return finish(mission, plan, results, out, run)
        finally:
            done.set()
            relay.join()


def finish(
    mission: MissionSpec, plan: MissionPlan, results: list[TrainResult], out: Path, run: RunJobs
) -> PipelineResult:
    """After every sub-task is trained: whole-mission rollouts, hand-over repair while below
    ``training.mission_target`` (its jobs go to ``run``; what it did goes to
    ``out/handover_repair.json``), then ``out/bundle.zip``."""
    seed = mission.training.seed + EVALUATION_SEED

    def evaluate(candidate: list[TrainResult], at: int) -> MissionEvaluation:
        return evaluate_results(mission, plan, candidate, at)

    evaluation = evaluate(results, seed)
    results, evaluation, repairs = repair_handovers(
        mission, plan, results, evaluation, out, evaluate, run, seed
    )
    record = {
        "rounds": [r.to_json() for r in repairs],
        "results": [r.to_json() for r in results],
        "mission_evaluation": evaluation.to_json(),
    }
    (out / REPAIR_RECORD).write_text(json.dumps(record, indent=1))
    return assemble(mission, plan, results, out / "bundle.zip", evaluation, repairs)


def subtask_jobs(mission: MissionSpec, plan: MissionPlan) -> list[SubtaskJob]:
    """One training job per sub-task of ``plan``, seeded ``training.seed + k``."""
    document, plan_doc = mission.model_dump(mode="json"), plan_to_dict(plan)
    training = mission.training
    return [
        SubtaskJob(
            mission=document, plan=plan_doc, subtask=k, training=training, seed=training.seed + k
        )
        for k in range(len(plan.subtasks))
    ]


def assemble(
    mission: MissionSpec,
    plan: MissionPlan,
    results: list[TrainResult],
    bundle: str | Path,
    evaluation: MissionEvaluation,
    repairs: list[RepairRound],
) -> PipelineResult:
    """The bundle at ``bundle`` of the results ``finish`` kept, with their mission rollouts."""
    from workers.bundle import write_bundle

    seeds = [r.seed for r in results]
    path = write_bundle(bundle, mission, plan, results, evaluation, seeds)
    return PipelineResult(
        bundle=path, plan=plan, results=results, evaluation=evaluation, repairs=repairs
    )


def _relay(updates: Any, done: threading.Event, on_progress: PipelineProgress | None) -> None:
    while True:
        try:
            item = updates.get(timeout=0.2)
        except queue.Empty:
            if done.is_set():
                return
            continue
        except (EOFError, OSError):
            return
        if on_progress is not None:
            on_progress(*item)


def evaluate_results(
    mission: MissionSpec, plan: MissionPlan, results: list[TrainResult], seed: int | None = None
) -> MissionEvaluation:
    """Whole-mission rollouts of the trained models (files this pipeline wrote), seeded
    ``seed`` (default ``training.seed + EVALUATION_SEED``)."""
    training = mission.training
    cls = ALGORITHMS[training.algorithm]
    models = [cls.load(r.model_path, device="cpu") for r in results]
    policies = [(lambda obs, m=m: m.predict(obs, deterministic=True)[0]) for m in models]
    env = MissionEnv(mission, plan, training.eval_env_options(mission.robot.model), training.cycles)
    try:
        act = stage_policies(env.sequence, policies)
        at = training.seed + EVALUATION_SEED if seed is None else seed
        return rollout_mission(act, env, training.mission_episodes, seed=at)
    finally:
        env.close()
