"""Evaluate sub-policies and the whole concatenated policy of a mission.

* ``evaluate_subtask``: N episodes of one sub-task env from its real start: success rate, mean
  steps to the goal, collision and timeout rates.
* ``rollout_mission``: N episodes of ``envs.mission_env.MissionEnv`` (the whole lasso driven by
  one robot handed from sub-task env to sub-task env) judged by the mission's Büchi automaton on
  the label trace: success = every goal reached without collision and the automaton accepts the
  trace with the last suffix cycle repeated forever (finite tasks: the last label forever).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from envs.mission_env import MissionEnv
from planner.geometry.pose import Pose

Act = Callable[[np.ndarray], np.ndarray]
"""A deterministic policy: observation -> action."""


@dataclass
class SubtaskEvaluation:
    """Outcome of ``episodes`` evaluation episodes of one sub-task policy."""

    episodes: int
    success_rate: float
    collision_rate: float
    timeout_rate: float
    mean_steps_to_goal: float | None
    """Mean episode length of the successful episodes (None: no success)."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def run_episode(act: Act, env: gym.Env[Any, Any], obs: Any) -> tuple[dict[str, Any], int]:
    """Step ``env`` with ``act`` from ``obs`` (just reset) to the end of the episode; the last
    step's info and the number of steps."""
    steps = 0
    while True:
        obs, _, terminated, truncated, info = env.step(act(obs))
        steps += 1
        if terminated or truncated:
            return info, steps


LANE_STRIDE = 1_000_003
"""Seeds of an evaluation's lanes are this far apart, so that evaluations seeded a few apart
(periodic, final, mission) never share a lane seed."""


def lane_seed(seed: int, lane: int) -> int:
    """The seed of lane ``lane`` of an evaluation seeded ``seed`` (lane 0: ``seed`` itself)."""
    return seed + LANE_STRIDE * lane


def seed_lanes(envs: Sequence[gym.Env[Any, Any]], seed: int) -> list[Any]:
    """Reset every lane with its ``lane_seed``: its first observation."""
    return [env.reset(seed=lane_seed(seed, j))[0] for j, env in enumerate(envs)]


def evaluate_subtask(
    act: Act, envs: gym.Env[Any, Any] | Sequence[gym.Env[Any, Any]], episodes: int, seed: int
) -> SubtaskEvaluation:
    """Run ``act`` for ``episodes`` episodes of one env, or of copies of one env stepped in
    lockstep (lanes: ``act`` then gets the batch of the running lanes' observations, one row
    per lane, and returns one action per row). Lane ``j`` is seeded once with
    ``lane_seed(seed, j)`` and runs ``(episodes + j) // lanes`` episodes one after another."""
    batched = not isinstance(envs, gym.Env)
    lanes: list[gym.Env[Any, Any]] = [envs] if isinstance(envs, gym.Env) else list(envs)
    lanes = lanes[:episodes]
    left = [(episodes + j) // len(lanes) for j in range(len(lanes))]
    obs = seed_lanes(lanes, seed)
    steps = [0] * len(lanes)
    outcomes = {"success": 0, "collision": 0, "timeout": 0}
    goal_steps: list[int] = []
    running = [j for j in range(len(lanes)) if left[j]]
    while running:
        if batched:
            actions = list(act(np.stack([obs[j] for j in running])))
        else:
            actions = [act(obs[j]) for j in running]
        still: list[int] = []
        for j, action in zip(running, actions, strict=True):
            obs[j], _, terminated, truncated, info = lanes[j].step(action)
            steps[j] += 1
            if not (terminated or truncated):
                still.append(j)
                continue
            outcome = _outcome(info)
            outcomes[outcome] += 1
            if outcome == "success":
                goal_steps.append(steps[j])
            steps[j], left[j] = 0, left[j] - 1
            if left[j]:
                obs[j], _ = lanes[j].reset()
                still.append(j)
        running = still
    return SubtaskEvaluation(
        episodes=episodes,
        success_rate=outcomes["success"] / episodes,
        collision_rate=outcomes["collision"] / episodes,
        timeout_rate=outcomes["timeout"] / episodes,
        mean_steps_to_goal=float(np.mean(goal_steps)) if goal_steps else None,
    )


def _outcome(info: dict[str, Any]) -> str:
    """How a sub-task episode ended, from its last step's info."""
    if info.get("is_success"):
        return "success"
    if info.get("collision") or info.get("violation"):
        return "collision"
    return "timeout"


@dataclass
class MissionEvaluation:
    """Outcome of whole-mission rollouts of a concatenated policy."""

    episodes: int
    cycles: int
    success_rate: float
    collision_rate: float
    timeout_rate: float
    rejected_rate: float
    """Every goal reached, yet the automaton rejects the labels met on the way."""
    mean_steps: float | None
    """Mean length of the successful rollouts."""
    failures: dict[str, dict[str, int]] = field(default_factory=dict)
    """Failures by sub-task index (as a string) and kind (collision, timeout, rejected)."""
    trails: list[list[list[float]]] = field(default_factory=list, repr=False)
    """Positions of the first few rollouts (for pictures; not in ``to_json``)."""
    handovers: dict[int, list[Pose]] = field(default_factory=dict, repr=False)
    """Every pose each sub-task took the robot over in, over all rollouts (not in
    ``to_json``)."""

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out.pop("trails")
        out.pop("handovers")
        return out

    def summary(self) -> str:
        """One line: the success rate and how the rest failed."""
        cycles = f", {self.cycles} suffix cycles" if self.cycles else ""
        return (
            f"success rate {100 * self.success_rate:.1f} % over {self.episodes} rollouts"
            f"{cycles}; collisions {100 * self.collision_rate:.1f} %, timeouts "
            f"{100 * self.timeout_rate:.1f} %, automaton rejections "
            f"{100 * self.rejected_rate:.1f} %"
        )


def rollout_mission(
    act: Act,
    env: MissionEnv,
    episodes: int,
    seed: int = 0,
    keep_trails: int = 3,
    reset: Callable[[np.ndarray], None] | None = None,
) -> MissionEvaluation:
    """Roll out ``act`` on ``env`` for ``episodes`` episodes (seeded once with ``seed``);
    ``reset(obs)`` is called at the start of each episode."""
    counts = {"collision": 0, "timeout": 0, "rejected": 0}
    failures: dict[str, dict[str, int]] = {}
    lengths: list[int] = []
    trails: list[list[list[float]]] = []
    handovers: dict[int, list[Pose]] = {}
    successes = 0
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed if episode == 0 else None)
        if reset is not None:
            reset(obs)
        info, steps = run_episode(act, env, obs)
        if episode < keep_trails:
            trails.append([list(p) for p in env.trail])
        for k, pose in env.handovers:
            handovers.setdefault(k, []).append(pose)
        if info["is_success"]:
            successes += 1
            lengths.append(steps)
            continue
        kind = str(info["failure"])
        counts[kind] += 1
        where = "mission" if info["failed_subtask"] is None else str(info["failed_subtask"])
        failures.setdefault(where, {}).setdefault(kind, 0)
        failures[where][kind] += 1
    return MissionEvaluation(
        episodes=episodes,
        cycles=env.cycles,
        success_rate=successes / episodes,
        collision_rate=counts["collision"] / episodes,
        timeout_rate=counts["timeout"] / episodes,
        rejected_rate=counts["rejected"] / episodes,
        mean_steps=float(np.mean(lengths)) if lengths else None,
        failures=failures,
        trails=trails,
        handovers=handovers,
    )


def stage_policies(sequence: Sequence[int], policies: Sequence[Act]) -> Act:
    """A concatenated policy over ``MissionEnv`` observations: the last entry is the stage,
    which picks the sub-policy ``policies[sequence[stage]]`` for the rest."""

    def act(obs: np.ndarray) -> np.ndarray:
        stage = min(round(float(obs[-1])), len(sequence) - 1)
        return policies[sequence[stage]](obs[:-1])

    return act
