"""The control beside a learned result: the zero action, evaluated as a trained policy is.

Under the default ``shaped`` protocol the env adds the robot's feed-forward to every action
(``envs.feedforward``), so the zero action is that controller alone: what it reaches is owed to
the env's defaults, not to training. ``zero_control`` measures it with the episodes and seeds of
a mission's reported figures: each sub-task's ``final_eval_episodes`` from its real starts at
its job's ``REPORT_SEED``, then ``mission_episodes`` whole-mission rollouts at
``EVALUATION_SEED``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from envs.mission_env import MissionEnv
from planner.plan import MissionPlan
from workers.evaluation import (
    Act,
    MissionEvaluation,
    SubtaskEvaluation,
    evaluate_subtask,
    rollout_mission,
)
from workers.jobs import job_seed
from workers.mission import MissionSpec
from workers.run import EVALUATION_SEED
from workers.training import REPORT_SEED, subtask_env


def zero_action(dim: int) -> Act:
    """The zero action for one observation or a batch of them (one row per lane)."""

    def act(observations: np.ndarray) -> np.ndarray:
        batch = np.asarray(observations)
        shape = (len(batch), dim) if batch.ndim > 1 else (dim,)
        return np.zeros(shape, dtype=np.float32)

    return act


@dataclass(frozen=True)
class ControlEvaluation:
    """The zero action's reported figures: one evaluation per sub-task, and the mission's."""

    subtasks: list[SubtaskEvaluation]
    mission: MissionEvaluation


def zero_control(mission: MissionSpec, plan: MissionPlan) -> ControlEvaluation:
    """The zero action on every sub-task of ``plan`` and on the whole mission (see the module
    docstring), on ``eval_lanes`` lanes."""
    training = mission.training
    lanes = training.eval_lanes
    subtasks = []
    for k in range(len(plan.subtasks)):
        envs = [subtask_env(mission, plan, training, k, evaluation=True) for _ in range(lanes)]
        try:
            act = zero_action(envs[0].robot.action_dim)
            seed = job_seed(training, k) + REPORT_SEED
            subtasks.append(evaluate_subtask(act, envs, training.final_eval_episodes, seed))
        finally:
            for env in envs:
                env.close()
    options = training.eval_env_options(mission.robot.model)
    wholes = [MissionEnv(mission, plan, options, training.cycles) for _ in range(lanes)]
    try:
        act = zero_action(wholes[0].robot.action_dim)
        seed = training.seed + EVALUATION_SEED
        rollouts = rollout_mission(act, wholes, training.mission_episodes, seed=seed)
    finally:
        for whole in wholes:
            whole.close()
    return ControlEvaluation(subtasks, rollouts)
