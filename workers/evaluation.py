"""Evaluate sub-policies and the whole concatenated policy of a mission.

* ``evaluate_subtask``: N episodes of one sub-task env from its real start: success rate, mean
  steps to the goal, collision and timeout rates.
* ``MissionEnv``: one robot driven through the lasso ``prefix · suffix^cycles``, each sub-task
  by its own env (the robot is handed over in place when a goal region is reached). Its
  observation is the current sub-task env's observation followed by the stage number, so a
  concatenated policy knows which sub-policy acts.
* ``rollout_mission``: N episodes of ``MissionEnv`` judged by the mission's Büchi automaton on
  the label trace: success = every goal reached without collision and the automaton accepts the
  trace with the last suffix cycle repeated forever (finite tasks: the last label forever).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.factory import make_env
from envs.nav_env import NavEnv
from envs.options import EnvOptions
from envs.robots import Robot, make_robot
from planner.decompose import lasso_stages, phases
from planner.geometry.pose import Pose
from planner.geometry.world import World
from planner.plan import MissionPlan
from workers.mission import MissionSpec

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


def evaluate_subtask(
    act: Act, env: gym.Env[Any, Any], episodes: int, seed: int
) -> SubtaskEvaluation:
    """Run ``act`` for ``episodes`` episodes of ``env`` (seeded once with ``seed``)."""
    successes = collisions = timeouts = 0
    goal_steps: list[int] = []
    obs, _ = env.reset(seed=seed)
    for episode in range(episodes):
        if episode:
            obs, _ = env.reset()
        info, steps = run_episode(act, env, obs)
        if info.get("is_success"):
            successes += 1
            goal_steps.append(steps)
        elif info.get("collision") or info.get("violation"):
            collisions += 1
        else:
            timeouts += 1
    return SubtaskEvaluation(
        episodes=episodes,
        success_rate=successes / episodes,
        collision_rate=collisions / episodes,
        timeout_rate=timeouts / episodes,
        mean_steps_to_goal=float(np.mean(goal_steps)) if goal_steps else None,
    )


class MissionEnv(gym.Env[np.ndarray, np.ndarray]):
    """The whole mission as one episode: sub-task envs sharing one robot, switched in place.

    ``options`` are the sub-task envs' options (``TrainingSpec.eval_env_options(model)``).
    Observation: the current sub-task env's observation, then the stage number (position in
    ``planner.decompose.lasso_stages``). Ends on a collision (``failure = "collision"``), a
    sub-task running out of steps (``"timeout"``) or after the last stage; then ``info`` holds
    ``accepted`` (the automaton's verdict on the label trace), ``is_success``,
    ``failed_subtask`` and ``failure``.
    """

    def __init__(
        self,
        mission: MissionSpec,
        plan: MissionPlan,
        options: EnvOptions,
        cycles: int = 3,
        world: World | None = None,
    ) -> None:
        self.mission, self.plan = mission, plan
        suffix = any(s.phase == "suffix" for s in plan.subtasks)
        self.cycles = cycles if suffix else 0
        """Suffix cycles of a rollout (0 for a finite task: no suffix sub-task)."""
        self.world = world if world is not None else mission.build_world()
        spec = mission.robot
        self.robot: Robot = make_robot(spec.model, self.world, spec.radius, spec.params)
        self.envs: list[NavEnv] = [
            make_env(
                mission, sub, "rrt", world=self.world, plan=plan, robot=self.robot, options=options
            )
            for sub in plan.subtasks
        ]
        self.sequence = lasso_stages(plan.subtasks, self.cycles)
        prefix, suffix = phases(plan.subtasks)
        self.prefix_stages = len(prefix)
        self.suffix_length = len(self.sequence) - self.prefix_stages
        self.cycle_length = max(1, len(suffix))
        space = self.envs[0].observation_space
        assert isinstance(space, spaces.Box)
        low = np.append(space.low, 0.0).astype(np.float32)
        high = np.append(space.high, float(len(self.sequence))).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = self.envs[0].action_space
        self._labels = self.world.labeler.point_labels
        self.stage = 0
        self.trace: list[frozenset[str]] = []
        """Labels met so far, stutter-free."""
        self.cycle_starts: list[int] = []
        """Index into ``trace`` where each suffix cycle began."""
        self.trail: list[list[float]] = []
        """Every position visited in this episode."""
        self.handovers: list[tuple[int, Pose]] = []
        """``(sub-task, pose)`` of every stage begun in this episode: where the robot stood
        (and faced) when that sub-task took it over."""

    def _obs(self, obs: np.ndarray) -> np.ndarray:
        return np.append(obs, np.float32(self.stage)).astype(np.float32)

    def _record(self) -> None:
        x = self.robot.position().tolist()
        self.trail.append(x)
        label = self._labels(x)
        if not self.trace or self.trace[-1] != label:
            self.trace.append(label)

    def _begin_stage(self) -> None:
        pose = Pose(self.robot.position(), self.robot.heading())
        self.handovers.append((self.sequence[self.stage], pose))
        into = self.stage - self.prefix_stages
        if into >= 0 and into % self.cycle_length == 0:
            self.cycle_starts.append(len(self.trace) - 1)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.stage = 0
        self.trace, self.cycle_starts, self.trail, self.handovers = [], [], [], []
        # Real start 0 of the first sub-task is the mission start (envs.handover).
        obs, info = self.envs[self.sequence[0]].reset(seed=seed, options={"start": 0})
        self._record()
        self._begin_stage()
        return self._obs(obs), {**info, "subtask": self.sequence[0], "stage": 0}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        k = self.sequence[self.stage]
        obs, reward, _, truncated, info = self.envs[k].step(action)
        self._record()
        out = {**info, "subtask": k, "stage": self.stage, "is_success": False}
        if info["collision"] or info["violation"]:
            return self._obs(obs), reward, True, False, self._end(out, k, "collision")
        if truncated and not info["is_success"]:
            return self._obs(obs), reward, False, True, self._end(out, k, "timeout")
        if not info["is_success"]:
            return self._obs(obs), reward, False, False, out
        self.stage += 1
        if self.stage == len(self.sequence):
            return self._obs(obs), reward, True, False, self._end(out, None, None)
        nxt = self.sequence[self.stage]
        self._begin_stage()
        obs, _ = self.envs[nxt].reset(options={"keep_robot": True})
        return self._obs(obs), reward, False, False, {**out, "subtask": nxt, "stage": self.stage}

    def accepted(self) -> bool:
        """The automaton's verdict on the trace: the last suffix cycle (the last label for a
        finite task) repeated forever after everything before it."""
        trace = self.trace
        if self.suffix_length and self.cycle_starts:
            start = self.cycle_starts[-1]
            prefix, cycle = trace[: start + 1], trace[start + 1 :] or [trace[start]]
        else:
            prefix, cycle = trace, [trace[-1]]
        return self.plan.nba.accepts_lasso(prefix, cycle)

    def _end(
        self, info: dict[str, Any], subtask: int | None, failure: str | None
    ) -> dict[str, Any]:
        accepted = failure is None and self.accepted()
        if failure is None and not accepted:
            failure = "rejected"
        return {
            **info,
            "accepted": accepted,
            "is_success": accepted,
            "failed_subtask": subtask,
            "failure": failure,
        }

    def close(self) -> None:
        for env in self.envs:
            env.close()
        self.robot.close()
        super().close()


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
