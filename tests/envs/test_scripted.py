"""Scripted controllers drive planned guides to their goals: the dynamics and rewards are sane.

A pure-pursuit controller follows the sub-task's planned path (a point a fixed distance ahead of
the robot's projection on it, which only moves forward). Every robot must reach the sub-task's
goal without crashing, earning ``R+`` on the way and ``R++`` at the end; the unicycle drives a
whole mission by handing one robot over between the sub-task envs; ``tl`` and ``g-rrt`` are
judged by the automaton.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from envs.factory import make_env
from envs.nav_env import NavEnv
from envs.robots import Robot
from planner.geometry.world import World
from tests.envs.test_nav_env import CLEARANCE, FINITE, INFINITE, ROBOT_IDS, ROBOTS, mission, planned


class Pursuit:
    """The point ``ahead`` metres beyond the robot's projection on ``path``; the projection only
    moves forward (within a window), so a path that passes near itself is followed in order."""

    def __init__(self, path: np.ndarray, ahead: float) -> None:
        keep = np.ones(len(path), dtype=bool)
        keep[1:] = np.any(np.diff(path, axis=0) != 0, axis=1)
        self.path = path[keep]
        seg = np.diff(self.path, axis=0)
        self.lengths = np.linalg.norm(seg, axis=1)
        self.cum = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.s = 0.0
        self.ahead = ahead

    def point(self, s: float) -> np.ndarray:
        s = min(max(s, 0.0), float(self.cum[-1]))
        j = min(int(np.searchsorted(self.cum, s, side="right")) - 1, len(self.lengths) - 1)
        if j < 0:
            return self.path[0].copy()
        t = (s - self.cum[j]) / self.lengths[j]
        return self.path[j] + t * (self.path[j + 1] - self.path[j])

    def target(self, x: np.ndarray) -> np.ndarray:
        window = np.linspace(self.s, self.s + 1.0, 41)
        pts = np.array([self.point(s) for s in window])
        self.s = float(window[int(np.argmin(np.linalg.norm(pts - x, axis=1)))])
        return self.point(self.s + self.ahead)


def heading_error(robot: Robot, target: np.ndarray) -> float:
    d = target - robot.position()
    return (math.atan2(d[1], d[0]) - float(robot.state[2]) + math.pi) % (2 * math.pi) - math.pi


def unicycle(robot: Robot, target: np.ndarray) -> np.ndarray:
    err = heading_error(robot, target)
    return np.array([0.8 * max(0.0, math.cos(err)), float(np.clip(2.0 * err, -1.0, 1.0))])


def racecar(robot: Robot, target: np.ndarray) -> np.ndarray:
    err = heading_error(robot, target)
    return np.array([0.7, float(np.clip(2.5 * err, -1.0, 1.0))])


def point(robot: Robot, target: np.ndarray) -> np.ndarray:
    d = robot.workspace_dim
    pos, vel = robot.state[:d], robot.state[d:]
    return np.clip(2.0 * (target - pos) - 2.5 * vel, -1.0, 1.0)


def quadrotor(robot: Robot, target: np.ndarray) -> np.ndarray:
    return np.clip(1.5 * (target - robot.position()), -0.8, 0.8)


CONTROLLERS: dict[str, Callable[[Robot, np.ndarray], np.ndarray]] = {
    "unicycle": unicycle,
    "racecar": racecar,
    "point": point,
    "quadrotor": quadrotor,
}


def into_goal(world: World, path: np.ndarray, goal: str) -> np.ndarray:
    """``path`` extended to the centre of its goal region: the planner may end a path on the
    region's boundary, and the env wants the robot inside."""
    lo, hi = world.regions[goal].bounding_box()
    return np.vstack([path, (lo + hi) / 2.0])


def drive(env: NavEnv, path: np.ndarray, ahead: float = 0.5) -> tuple[list[float], dict]:
    """Follow ``path`` (then into the goal region) until the episode ends; the rewards and the
    last info."""
    goal = env.legs[0].subtask.goal
    if goal and env.mode.name != "g-rrt":
        path = into_goal(env.world, path, goal)
    pursuit, control = Pursuit(path, ahead), CONTROLLERS[env.robot.name]
    rewards: list[float] = []
    for _ in range(env.max_steps):
        action = control(env.robot, pursuit.target(env.robot.position()))
        _, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        if terminated or truncated:
            return rewards, info
    raise AssertionError("the env did not end the episode at its step limit")


@pytest.mark.parametrize(("model", "dim", "radius"), ROBOTS, ids=ROBOT_IDS)
def test_every_robot_reaches_its_first_goal_with_paper_rewards(
    model: str, dim: int, radius: float
) -> None:
    # The racecar turns on a 0.6 m radius: its guide keeps a wider berth around corners.
    world, plan = planned(dim, FINITE, 0.7 if model == "racecar" else CLEARANCE)
    sub = plan.subtasks[0]
    env = make_env(mission(model, dim, radius), sub, "rrt-paper", world=world, plan=plan)
    try:
        env.reset(seed=0)
        rewards, info = drive(env, sub.path)
    finally:
        env.close()
    assert info["is_success"] is True, f"ended without success: {info}"
    assert not info["collision"] and rewards[-1] == 200.0
    plus = [r for r in rewards[:-1] if r != 0.0]
    assert plus and set(plus) == {5.0}
    # Reaching the goal region comes near the end of the guide: most balls were earned.
    assert len(plus) >= 0.6 * env.legs[0].guide.num_balls


def test_unicycle_drives_the_whole_mission_handing_the_robot_over() -> None:
    world, plan = planned(2, INFINITE)
    first = make_env(mission("unicycle", 2), plan.subtasks[0], "rrt", world=world, plan=plan)
    chain = [first] + [
        make_env(mission("unicycle", 2), sub, "rrt", world=world, plan=plan, robot=first.robot)
        for sub in plan.subtasks[1:]
    ]
    try:
        for k, env in enumerate(chain):
            env.reset(seed=0, options={"keep_robot": True} if k else None)
            rewards, info = drive(env, env.legs[0].subtask.path)
            assert info["is_success"] is True and rewards[-1] == 20.0, f"sub-task {k}: {info}"
            assert env.legs[0].subtask.goal in world.labels(env.robot.position())
            gained = sum(rewards[:-1]) + 0.01 * (len(rewards) - 1)
            # 0.5 per metre of guide, up to the ball where the goal region was entered.
            progress = env.legs[0].guide.length - info["distance_to_go"]
            assert gained == pytest.approx(0.5 * progress, abs=1e-9) and gained > 0
    finally:
        for env in chain:
            env.close()


def test_tl_rewards_only_the_automaton_transition() -> None:
    world, plan = planned(2, INFINITE)
    sub = plan.subtasks[0]
    env = make_env(mission("point", 2), sub, "tl", world=world, plan=plan)
    env.reset(seed=0)
    rewards, info = drive(env, sub.path)
    assert info["is_success"] is True and rewards[-1] == 20.0
    assert set(rewards[:-1]) == {0.0}
    assert sub.goal in world.labels(env.robot.position())


def test_g_rrt_drives_the_whole_lasso_stage_by_stage() -> None:
    world, plan = planned(2, INFINITE)
    env = make_env(mission("point", 2), None, "g-rrt", world=world, plan=plan)
    path = np.vstack([into_goal(world, s.path, s.goal) for s in plan.subtasks])
    env.reset(seed=0)
    pursuit, stages, rewards = Pursuit(path, 0.5), [], []
    for _ in range(env.max_steps):
        action = point(env.robot, pursuit.target(env.robot.position()))
        _, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        stages.append(info["stage"])
        if terminated or truncated:
            break
    assert info["is_success"] is True and rewards[-1] == 20.0
    assert stages == sorted(stages) and stages[-1] == len(plan.subtasks) - 1
    assert sum(r > 0 for r in rewards[:-1]) > 10
    assert info["progress_index"] >= env.num_balls - env.legs[-1].guide.num_balls
