"""Handover poses: where the concatenated policy hands the robot to each sub-task."""

from __future__ import annotations

import math

import numpy as np
import pytest

from envs.errors import EnvConfigError
from envs.factory import make_env
from envs.handover import INSIDE, arrival_pose, predecessors
from planner.decompose import SubTask
from planner.geometry.pose import Pose
from planner.geometry.shapes import Box
from planner.geometry.world import World
from tests.envs.test_nav_env import FINITE, INFINITE, mission, planned


def _sub(index: int, phase: str, path: list[list[float]], goal: str = "g") -> SubTask:
    points = np.array(path, dtype=float)
    return SubTask(index, phase, goal, points[0].copy(), points, 0, 1)  # type: ignore[arg-type]


def _box_world() -> World:
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [],
        {"g": Box(np.array([4.0, 4.0]), np.array([6.0, 6.0]))},
    )


def test_predecessors_follow_the_rollout_order() -> None:
    path = [[0.0, 0.0], [1.0, 0.0]]
    prefix_only = [_sub(i, "prefix", path) for i in range(3)]
    assert [predecessors(prefix_only, k) for k in range(3)] == [[None], [0], [1]]
    lasso = [_sub(0, "prefix", path), _sub(1, "suffix", path), _sub(2, "suffix", path)]
    assert [predecessors(lasso, k) for k in range(3)] == [[None], [0, 2], [1]]
    no_prefix = [_sub(0, "suffix", path), _sub(1, "suffix", path)]
    assert [predecessors(no_prefix, k) for k in range(2)] == [[None, 1], [0]]
    single_suffix = [_sub(0, "prefix", path), _sub(1, "suffix", path)]
    assert predecessors(single_suffix, 1) == [0, 1]


def test_arrival_pose_is_just_inside_the_goal_region_facing_along_the_guide() -> None:
    world = _box_world()
    pose = arrival_pose(world, _sub(0, "prefix", [[1.0, 1.0], [1.0, 5.0], [9.0, 5.0]]))
    assert pose.position[1] == pytest.approx(5.0)
    assert 4.0 + INSIDE <= pose.position[0] <= 4.0 + INSIDE + 0.03
    assert pose.heading == pytest.approx(0.0)
    diagonal = arrival_pose(world, _sub(0, "prefix", [[1.0, 1.0], [5.0, 5.0]]))
    assert diagonal.heading == pytest.approx(math.pi / 4)
    assert world.regions["g"].contains(diagonal.position[None, :])[0]


def test_arrival_pose_without_goal_region_is_the_guide_end() -> None:
    pose = arrival_pose(_box_world(), _sub(0, "prefix", [[1.0, 1.0], [1.0, 3.0]], goal=""))
    np.testing.assert_allclose(pose.position, [1.0, 3.0])
    assert pose.heading == pytest.approx(math.pi / 2)


def test_a_guide_that_never_enters_its_region_is_refused() -> None:
    with pytest.raises(EnvConfigError, match="never enters region 'g'"):
        arrival_pose(_box_world(), _sub(3, "prefix", [[1.0, 1.0], [1.0, 3.0]]))


@pytest.mark.parametrize("task", [FINITE, INFINITE])
def test_envs_start_where_the_previous_sub_task_hands_over(task: str) -> None:
    world, plan = planned(2, task)
    spec = mission("unicycle", 2, heading=0.3)
    for k in range(len(plan.subtasks)):
        env = make_env(spec, k, "rrt", world=world, plan=plan)
        expected = [
            Pose(np.asarray(spec.robot.position()), 0.3)
            if p is None
            else arrival_pose(world, plan.subtasks[p])
            for p in predecessors(plan.subtasks, k)
        ]
        assert len(env.starts) == len(expected)
        for pose, want in zip(env.starts, expected, strict=True):
            np.testing.assert_allclose(pose.position, want.position)
            assert pose.heading == pytest.approx(want.heading)
        seen = set()
        for _ in range(30):
            env.reset()
            _, _, cos, sin = env.robot.observation()[:4]
            distances = [
                np.linalg.norm(p.position - env.robot.position())
                + abs(math.remainder(p.heading - math.atan2(sin, cos), math.tau))
                for p in env.starts
            ]
            assert min(distances) < 1e-5
            seen.add(int(np.argmin(distances)))
        assert seen == set(range(len(env.starts)))
        env.reset(options={"start": 0})
        np.testing.assert_allclose(env.robot.position(), env.starts[0].position)
        env.close()


def test_handover_off_starts_at_the_guide_start_facing_along_it() -> None:
    world, plan = planned(2, FINITE)
    env = make_env(mission("unicycle", 2), 1, "rrt", world=world, plan=plan, handover=False)
    assert len(env.starts) == 1
    np.testing.assert_allclose(env.starts[0].position, plan.subtasks[1].start)
    assert env.starts[0].heading == pytest.approx(env.legs[0].headings[0])
    env.close()


@pytest.mark.parametrize("bad", [1, -1, True, "0", 0.0])
def test_a_bad_start_index_is_refused(bad: object) -> None:
    world, plan = planned(2, FINITE)
    env = make_env(mission("unicycle", 2), 0, "rrt", world=world, plan=plan)
    with pytest.raises(ValueError, match="start must index one of 1 starts"):
        env.reset(options={"start": bad})
    env.close()
