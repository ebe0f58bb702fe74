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

At most ``training.handover_rounds`` rounds. The pieces are plain functions so that both drivers
run the rounds their way: ``MissionRun.repair`` loops over them with a process pool (``ltlnav
train``), the service runs each round's jobs as job rows of their own, in parallel, and judges
the round in its next assembly step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.geometry.pose import Pose
from workers.evaluation import MissionEvaluation
from workers.jobs import SubtaskJob
from workers.stopwatch import added
from workers.train_result import TrainResult
from workers.training_spec import TrainingSpec

REPAIR_CURRICULUM = 0.3
"""Share of repair episodes that start at a random r-ball of the guide (unless the mission's
``training.env`` sets ``curriculum``): lower than in first training, since the starts are the
point of a repair, yet enough to keep the rest of the guide trained."""

MAX_STARTS = 300
"""Hand-over poses kept per sub-task (evenly thinned beyond it)."""

PROBE_SEED = 1000
"""Offset of the probe rollouts' seed from ``training.seed`` (per round)."""


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

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> RepairRound:
        return cls(**doc)


def probe_seed(training: TrainingSpec, round_: int) -> int:
    """Seed of the probe rollouts of round ``round_``: apart from the reported evaluation's."""
    return training.seed + PROBE_SEED * round_


def repair_training(training: TrainingSpec) -> TrainingSpec:
    """The training section of a repair job: ``handover_steps`` of budget and the repair
    curriculum (unless the mission sets its own)."""
    update: dict[str, Any] = {
        "n_timesteps": training.handover_steps,
        "env": {"curriculum": REPAIR_CURRICULUM, **training.env},
    }
    return training.model_copy(update=update)


def repair_jobs(
    training: TrainingSpec,
    results: Sequence[TrainResult],
    probe: MissionEvaluation,
    round_: int,
) -> list[SubtaskJob]:
    """One job per sub-task ``probe`` failed in and handed the robot to: train on from its
    current policy (``results``) with the probe's hand-over poses as starts."""
    again = repair_training(training)
    failing = sorted(int(k) for k in probe.failures if k != "mission")
    jobs = []
    for k in failing:
        poses = probe.handovers.get(k, [])
        if not poses:
            continue
        before = results[k]
        jobs.append(
            SubtaskJob(
                subtask=k,
                training=again,
                seed=before.seed + PROBE_SEED * round_,
                round=round_,
                starts=start_poses(poses),
                warm_start=Path(before.model_path).parent,
            )
        )
    return jobs


def start_poses(poses: Sequence[Pose]) -> tuple[Pose, ...]:
    """``poses`` as job starts, at most ``MAX_STARTS`` of them (evenly spaced)."""
    step = max(1, -(-len(poses) // MAX_STARTS))
    return tuple(poses[::step])


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
        selection=[(offset + s, r, n) for s, r, n in repair.selection],
        seconds=before.seconds + repair.seconds,
        parts=added(before.parts, repair.parts),
        repairs=before.repairs + 1,
    )


def candidate_results(
    results: Sequence[TrainResult], repaired: Sequence[TrainResult]
) -> list[TrainResult]:
    """``results`` with each repaired sub-task's result merged in."""
    candidate = list(results)
    for result in repaired:
        candidate[result.subtask] = merged(results[result.subtask], result)
    return candidate


def kept_results(
    rounds: Sequence[Sequence[TrainResult]], judged: Sequence[RepairRound]
) -> list[TrainResult]:
    """The results a run keeps: round 0's (the sub-tasks' own training), with the results of
    every judged round that was kept merged in (``rounds[r]``: round ``r``'s results)."""
    results = list(rounds[0])
    for record in judged:
        if record.kept:
            results = candidate_results(results, rounds[record.round])
    return results


def judged_round(
    round_: int, repaired: Sequence[TrainResult], before: float, after: float, seconds: float
) -> RepairRound:
    """The record of round ``round_`` that took the mission's success rate from ``before`` to
    ``after``: kept only if it went up."""
    return RepairRound(
        round=round_,
        subtasks=[r.subtask for r in repaired],
        success_before=before,
        success_after=after,
        kept=after > before,
        seconds=seconds,
    )
