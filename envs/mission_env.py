"""The whole mission as one env: the lasso ``prefix · suffix^cycles`` driven by one robot.

Each sub-task is driven by its own navigation env (``envs.factory.make_env``); the robot is
shared and handed over in place when a goal region is reached. The observation is the current
sub-task env's observation followed by the stage number, so a concatenated policy knows which
sub-policy acts. At the end the mission's Büchi automaton judges the label trace
(``workers.evaluation.rollout_mission`` runs the episodes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.factory import MissionLike, make_env
from envs.nav_env import NavEnv
from envs.options import EnvOptions
from envs.robots import Robot, make_robot
from planner.decompose import lasso_stages, phases
from planner.geometry.pose import Pose
from planner.geometry.world import World

if TYPE_CHECKING:
    from planner.plan import MissionPlan


class BuiltMission(MissionLike, Protocol):
    """What ``MissionEnv`` needs of a mission: ``make_env``'s world section and robot, and its
    built world (cached by ``workers.mission.MissionSpec``, so every env of a mission shares
    one world)."""

    def build_world(self) -> World: ...


class MissionEnv(gym.Env[np.ndarray, np.ndarray]):
    """The whole mission as one episode: sub-task envs sharing one robot, switched in place.

    ``mission`` is read for its world and robot (``workers.mission.MissionSpec`` fits);
    ``world`` is its prebuilt world (default ``mission.build_world()``). ``options`` are the
    sub-task envs' options (``TrainingSpec.eval_env_options(model)``), ``cycles`` the suffix
    cycles of an episode.
    Observation: the current sub-task env's observation, then the stage number (position in
    ``planner.decompose.lasso_stages``). Ends on a collision (``failure = "collision"``), a
    sub-task leaving its automaton stage (``"rejected"``, filed under that sub-task), a
    sub-task running out of steps (``"timeout"``) or after the last stage, where the automaton
    judges the whole trace (``"rejected"`` without a sub-task when it refuses); then ``info`` holds
    ``accepted`` (the automaton's verdict on the label trace), ``is_success``,
    ``failed_subtask`` and ``failure``.
    """

    def __init__(
        self,
        mission: BuiltMission,
        plan: MissionPlan,
        options: EnvOptions,
        cycles: int = 3,
        world: World | None = None,
    ) -> None:
        self.mission, self.plan = mission, plan
        prefix, suffix = phases(plan.subtasks)
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
            failure = "collision" if info["collision"] else "rejected"
            return self._obs(obs), reward, True, False, self._end(out, k, failure)
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
