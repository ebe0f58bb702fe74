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
from itertools import pairwise
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
    rejected_rate: float = 0.0
    """Episodes that left the sub-task's automaton stage (entered a region the task forbids
    there); 0 in records written before it was counted apart from collisions."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


LANE_STRIDE = 1_000_003
"""Seeds of an evaluation's lanes are this far apart, so that evaluations seeded a few apart
(periodic, final, mission) never share a lane seed."""


def lane_seed(seed: int, lane: int) -> int:
    """The seed of lane ``lane`` of an evaluation seeded ``seed`` (lane 0: ``seed`` itself)."""
    return seed + LANE_STRIDE * lane


def seed_lanes(envs: Sequence[gym.Env[Any, Any]], seed: int, first: int = 0) -> list[Any]:
    """Reset every lane with its ``lane_seed`` (the envs are lanes ``first``, ``first + 1``,
    ...): its first observation."""
    return [env.reset(seed=lane_seed(seed, first + j))[0] for j, env in enumerate(envs)]


Lanes = gym.Env[Any, Any] | Sequence[gym.Env[Any, Any]]
"""One env, or copies of one env stepped in lockstep (lanes)."""


@dataclass(frozen=True)
class LaneShare:
    """Lanes ``first`` to ``first + count - 1`` of an evaluation on ``total`` lanes: the part
    one process runs. Lane ``g`` is seeded ``lane_seed(seed, g)`` and runs ``(episodes + g) //
    total`` episodes whichever process runs it, so the parts together are the whole."""

    first: int
    count: int
    total: int

    def episodes(self, episodes: int) -> list[int]:
        """Episodes each lane of the share runs, of an evaluation of ``episodes``."""
        return [(episodes + self.first + j) // self.total for j in range(self.count)]


def lane_shares(total: int, parts: int) -> list[LaneShare]:
    """``total`` lanes cut into at most ``parts`` shares of nearly equal size."""
    parts = max(1, min(parts, total))
    bounds = [total * k // parts for k in range(parts + 1)]
    return [LaneShare(a, b - a, total) for a, b in pairwise(bounds)]


def run_lanes(
    act: Act,
    envs: Lanes,
    episodes: int,
    seed: int,
    ended: Callable[[gym.Env[Any, Any], dict[str, Any], int], None],
    reset: Callable[[np.ndarray], None] | None = None,
    share: LaneShare | None = None,
    stop: Callable[[], bool] | None = None,
) -> None:
    """Run ``episodes`` episodes of ``act`` on one env, or on lanes in lockstep (``act`` then
    gets the batch of the running lanes' observations, one row per lane, and returns one action
    per row). Lane ``j`` is seeded once with ``lane_seed(seed, j)`` and runs
    ``(episodes + j) // lanes`` episodes one after another; with ``share`` the envs are that
    share's lanes of a larger evaluation (``LaneShare``). ``ended(env, info, steps)`` hears
    every episode's end before its env is reset; ``reset(obs)`` every start. ``stop()``, asked
    after every episode's end, ends the run there (the other lanes' episodes are dropped)."""
    batched = not isinstance(envs, gym.Env)
    lanes: list[gym.Env[Any, Any]] = [envs] if isinstance(envs, gym.Env) else list(envs)
    if share is None:
        lanes = lanes[:episodes]
        share = LaneShare(0, len(lanes), len(lanes))
    if len(lanes) != share.count:
        raise ValueError(f"{len(lanes)} envs for a share of {share.count} lanes")
    left = share.episodes(episodes)
    obs = seed_lanes(lanes, seed, share.first)
    for first in obs:
        if reset is not None:
            reset(first)
    steps = [0] * len(lanes)
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
            ended(lanes[j], info, steps[j])
            if stop is not None and stop():
                return
            steps[j], left[j] = 0, left[j] - 1
            if left[j]:
                obs[j], _ = lanes[j].reset()
                if reset is not None:
                    reset(obs[j])
                still.append(j)
        running = still


def successes_needed(episodes: int, target: float) -> int:
    """The fewest successes of ``episodes`` whose rate reaches ``target`` (at most 1)."""
    return next(n for n in range(episodes + 1) if n / episodes >= target)


def evaluate_subtask(
    act: Act, envs: Lanes, episodes: int, seed: int, needed: int = 0
) -> SubtaskEvaluation:
    """Run ``act`` for ``episodes`` episodes of one sub-task env, or of its lanes
    (``run_lanes``). With ``needed``, stop as soon as fewer than ``needed`` successes can still
    be reached: the evaluation's ``episodes`` are then those run, and its rates are over them
    (below ``needed / episodes`` whatever the rest would have given)."""
    outcomes = {"success": 0, "collision": 0, "timeout": 0, "rejected": 0}
    goal_steps: list[int] = []

    def ended(_env: gym.Env[Any, Any], info: dict[str, Any], steps: int) -> None:
        outcome = _outcome(info)
        outcomes[outcome] += 1
        if outcome == "success":
            goal_steps.append(steps)

    def out_of_reach() -> bool:
        return sum(outcomes.values()) - outcomes["success"] > episodes - needed

    run_lanes(act, envs, episodes, seed, ended, stop=out_of_reach if needed else None)
    ran = sum(outcomes.values())
    return SubtaskEvaluation(
        episodes=ran,
        success_rate=outcomes["success"] / ran,
        collision_rate=outcomes["collision"] / ran,
        timeout_rate=outcomes["timeout"] / ran,
        mean_steps_to_goal=float(np.mean(goal_steps)) if goal_steps else None,
        rejected_rate=outcomes["rejected"] / ran,
    )


def _outcome(info: dict[str, Any]) -> str:
    """How a sub-task episode ended, from its last step's info."""
    if info.get("is_success"):
        return "success"
    if info.get("collision"):
        return "collision"
    if info.get("violation"):
        return "rejected"
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
    """The automaton rejects the labels met: in a sub-task that left its automaton stage (filed
    under it in ``failures``) or, every goal reached, on the whole trace (filed under
    ``"mission"``)."""
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
    envs: MissionEnv | Sequence[MissionEnv],
    episodes: int,
    seed: int = 0,
    keep_trails: int = 3,
    reset: Callable[[np.ndarray], None] | None = None,
    share: LaneShare | None = None,
) -> MissionEvaluation:
    """Roll out ``act`` on one ``MissionEnv`` or on its lanes (``run_lanes``) for ``episodes``
    episodes; ``reset(obs)`` is called at the start of each episode. With ``share`` only that
    share's episodes run (``merge_evaluations`` joins the shares)."""
    counts = {"collision": 0, "timeout": 0, "rejected": 0}
    failures: dict[str, dict[str, int]] = {}
    lengths: list[int] = []
    trails: list[list[list[float]]] = []
    handovers: dict[int, list[Pose]] = {}
    successes = 0

    def ended(lane: gym.Env[Any, Any], info: dict[str, Any], steps: int) -> None:
        nonlocal successes
        assert isinstance(lane, MissionEnv)
        if len(trails) < keep_trails:
            trails.append([list(p) for p in lane.trail])
        for k, pose in lane.handovers:
            handovers.setdefault(k, []).append(pose)
        if info["is_success"]:
            successes += 1
            lengths.append(steps)
            return
        kind = str(info["failure"])
        counts[kind] += 1
        where = "mission" if info["failed_subtask"] is None else str(info["failed_subtask"])
        failures.setdefault(where, {}).setdefault(kind, 0)
        failures[where][kind] += 1

    run_lanes(act, envs, episodes, seed, ended, reset, share)
    one = envs if isinstance(envs, MissionEnv) else envs[0]
    ran = episodes if share is None else sum(share.episodes(episodes))
    return MissionEvaluation(
        episodes=ran,
        cycles=one.cycles,
        success_rate=successes / ran,
        collision_rate=counts["collision"] / ran,
        timeout_rate=counts["timeout"] / ran,
        rejected_rate=counts["rejected"] / ran,
        mean_steps=float(np.mean(lengths)) if lengths else None,
        failures=failures,
        trails=trails,
        handovers=handovers,
    )


def merge_evaluations(
    parts: Sequence[MissionEvaluation], keep_trails: int = 3
) -> MissionEvaluation:
    """One evaluation of the rollouts of ``parts`` (the shares of one evaluation, in order)."""
    episodes = sum(p.episodes for p in parts)
    successes = [round(p.success_rate * p.episodes) for p in parts]
    steps = sum(n * p.mean_steps for n, p in zip(successes, parts, strict=True) if p.mean_steps)
    failures: dict[str, dict[str, int]] = {}
    handovers: dict[int, list[Pose]] = {}
    for part in parts:
        for where, kinds in part.failures.items():
            for kind, count in kinds.items():
                failures.setdefault(where, {}).setdefault(kind, 0)
                failures[where][kind] += count
        for k, poses in part.handovers.items():
            handovers.setdefault(k, []).extend(poses)

    def rate(name: str) -> float:
        return sum(getattr(p, name) * p.episodes for p in parts) / episodes

    return MissionEvaluation(
        episodes=episodes,
        cycles=parts[0].cycles,
        success_rate=sum(successes) / episodes,
        collision_rate=rate("collision_rate"),
        timeout_rate=rate("timeout_rate"),
        rejected_rate=rate("rejected_rate"),
        mean_steps=steps / sum(successes) if sum(successes) else None,
        failures=failures,
        trails=[trail for p in parts for trail in p.trails][:keep_trails],
        handovers=handovers,
    )


def stage_policies(sequence: Sequence[int], policies: Sequence[Act]) -> Act:
    """A concatenated policy over ``MissionEnv`` observations: the last entry is the stage,
    which picks the sub-policy ``policies[sequence[stage]]`` for the rest. It takes one
    observation, or a batch (one row per lane: each sub-policy is called once on its rows)."""
    order = np.asarray(sequence)

    def stage_of(obs: np.ndarray) -> np.ndarray:
        return order[np.minimum(np.rint(obs[..., -1]).astype(int), len(sequence) - 1)]

    def act(obs: np.ndarray) -> np.ndarray:
        if obs.ndim == 1:
            return policies[int(stage_of(obs))](obs[:-1])
        which = stage_of(obs)
        actions: np.ndarray | None = None
        for k in np.unique(which):
            rows = which == k
            part = np.asarray(policies[int(k)](obs[rows, :-1]))
            if actions is None:
                actions = np.empty((len(obs), *part.shape[1:]), dtype=part.dtype)
            actions[rows] = part
        assert actions is not None
        return actions

    return act
