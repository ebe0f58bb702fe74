"""Hand-over repair: train sub-tasks on from the poses whole-mission rollouts hand them over in.

Every sub-task first trains on its own, in parallel, from its nominal hand-over pose
(``envs.handover``). A mission rollout hands the robot over wherever the predecessor's policy
first enters its goal region, which is not that pose: on the car mission the arrivals lay
0.41-0.43 m from it and sub-task 2 then collided in 13 of 100 rollouts (``bench/LEARNING.md``).

So, while the mission's success rate is below ``training.mission_target``, a round of repair:

1. probe rollouts of the mission (seeded apart from the reported evaluation, so the repaired
   policies are never trained on the hand-over poses of the rollouts that judge them) record
   every pose each sub-task took the robot over in;
2. each sub-task the probe failed in trains on from its own policy and replay buffer, with
   those poses as its starts (``SubtaskJob.starts``), until its success rate from them reaches
   ``target_success`` or ``handover_steps`` run out;
3. the mission is evaluated again and the round is kept only if its success rate went up.

At most ``training.handover_rounds`` rounds.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from envs.handover import Pose
from planner.plan import MissionPlan
from planner.serialize import plan_to_dict
from workers.evaluation import MissionEvaluation
from workers.mission import MissionSpec
from workers.training import TrainResult
from workers.training_spec import StartPose, SubtaskJob

REPAIR_CURRICULUM = 0.3
"""Share of repair episodes that start at a random r-ball of the guide (unless the mission's
``training.env`` sets ``curriculum``): lower than in first training, since the starts are the
point of a repair, yet enough to keep the rest of the guide trained."""

MAX_STARTS = 300
"""Hand-over poses kept per sub-task (evenly thinned beyond it)."""

PROBE_SEED = 1000
"""Offset of the probe rollouts' seed from ``training.seed`` (per round)."""

Evaluate = Callable[[list[TrainResult], int], MissionEvaluation]
"""``evaluate(results, seed)``: whole-mission rollouts of these sub-task results."""

RunJobs = Callable[[list[tuple[SubtaskJob, Path, int]]], list[TrainResult]]
"""Run jobs ``(job, out_dir, steps before)`` (in parallel) and return their results."""


@dataclass(frozen=True)
class RepairRound:
    """What one round of hand-over repair did."""

    round: int
    subtasks: list[int]
    """Sub-tasks trained on in this round."""
    success_before: float
    success_after: float
    kept: bool
    """Whether the repaired policies replaced the earlier ones (the mission improved)."""
    seconds: float
    """Wall time of the round: probe rollouts, training, evaluation."""

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def repair_jobs(
    mission: MissionSpec,
    plan: MissionPlan,
    results: Sequence[TrainResult],
    probe: MissionEvaluation,
    round_: int,
    out_dir: Path,
) -> list[tuple[SubtaskJob, Path]]:
    """One job per sub-task ``probe`` failed in and handed the robot to: train on from its
    current policy (``results``) with the probe's hand-over poses as starts."""
    training = mission.training
    update: dict[str, Any] = {
        "n_timesteps": training.handover_steps,
        "env": {"curriculum": REPAIR_CURRICULUM, **training.env},
    }
    repair_training = training.model_copy(update=update)
    document, plan_doc = mission.model_dump(mode="json"), plan_to_dict(plan)
    failing = sorted(int(k) for k in probe.failures if k != "mission")
    jobs = []
    for k in failing:
        poses = probe.handovers.get(k, [])
        if not poses:
            continue
        before = results[k]
        job = SubtaskJob(
            mission=document,
            plan=plan_doc,
            subtask=k,
            training=repair_training,
            seed=before.seed + PROBE_SEED * round_,
            starts=start_poses(poses),
            warm_start=str(Path(before.model_path).parent),
        )
        jobs.append((job, out_dir / f"subtask_{k}" / f"handover_{round_}"))
    return jobs


def start_poses(poses: Sequence[Pose]) -> list[StartPose]:
    """``poses`` as job starts, at most ``MAX_STARTS`` of them (evenly spaced)."""
    step = max(1, -(-len(poses) // MAX_STARTS))
    return [
        StartPose(position=[float(v) for v in p.position], heading=float(p.heading))
        for p in poses[::step]
    ]


def merged(before: TrainResult, repair: TrainResult) -> TrainResult:
    """The result of a sub-task after a repair: the repaired policy and its evaluation (from
    the hand-over poses), with steps, curve and time counted over both."""
    offset = before.steps
    policy_steps = None if repair.policy_steps is None else offset + repair.policy_steps
    return dataclasses.replace(
        repair,
        seed=before.seed,
        steps=offset + repair.steps,
        resumed_from=before.resumed_from,
        policy_steps=policy_steps,
        curve=before.curve + [(offset + s, r) for s, r in repair.curve],
        seconds=before.seconds + repair.seconds,
        repairs=before.repairs + 1,
    )


def repair_handovers(
    mission: MissionSpec,
    plan: MissionPlan,
    results: list[TrainResult],
    evaluation: MissionEvaluation,
    out_dir: Path,
    evaluate: Evaluate,
    run: RunJobs,
    evaluation_seed: int,
) -> tuple[list[TrainResult], MissionEvaluation, list[RepairRound]]:
    """Rounds of hand-over repair (see the module docstring) from ``results`` and their
    mission ``evaluation`` (rolled out with ``evaluation_seed``); the results and evaluation to
    keep, and what each round did."""
    training = mission.training
    rounds: list[RepairRound] = []
    for round_ in range(1, training.handover_rounds + 1):
        if evaluation.success_rate >= training.mission_target:
            break
        t0 = time.monotonic()
        probe = evaluate(results, training.seed + PROBE_SEED * round_)
        jobs = repair_jobs(mission, plan, results, probe, round_, out_dir)
        if not jobs:
            break
        repaired = run([(job, folder, results[job.subtask].steps) for job, folder in jobs])
        candidate = list(results)
        for (job, _), result in zip(jobs, repaired, strict=True):
            candidate[job.subtask] = merged(results[job.subtask], result)
        after = evaluate(candidate, evaluation_seed)
        kept = after.success_rate > evaluation.success_rate
        rounds.append(
            RepairRound(
                round=round_,
                subtasks=[job.subtask for job, _ in jobs],
                success_before=evaluation.success_rate,
                success_after=after.success_rate,
                kept=kept,
                seconds=time.monotonic() - t0,
            )
        )
        if not kept:
            break
        results, evaluation = candidate, after
    return results, evaluation, rounds
