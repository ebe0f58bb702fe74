"""A racecar that starts facing a wall, away from its goal, in a lane too narrow to loop in:
its redrawn guide backs into a hall that opens off the lane (a three-point turn), and the
pursuit feed-forward drives it, backwards then forwards."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np

from envs.drivable import clearances, redraw_course
from envs.factory import make_env
from envs.robots import robot_params
from envs.spec import RobotSpec
from planner.geometry.pose import Pose
from planner.geometry.shapes import Ball, Box
from planner.geometry.world import World
from planner.plan import MissionPlan, plan_mission
from planner.search.planner_spec import PlannerSpec
from tests.envs.test_nav_env import Mission, Prebuilt

RADIUS = 0.27
FACTOR = 1.45
START = [2.0, 2.0, math.pi]


@cache
def lane() -> tuple[World, MissionPlan]:
    world = World(
        np.array([[0.0, 12.0], [0.0, 8.0]]),
        [
            Box(np.array([0.0, 0.0]), np.array([12.0, 1.2])),
            Box(np.array([0.0, 2.8]), np.array([4.0, 8.0])),
            Box(np.array([7.0, 2.8]), np.array([12.0, 8.0])),
            Box(np.array([0.0, 0.0]), np.array([1.0, 8.0])),
        ],
        {"a": Ball(np.array([10.5, 2.0]), 0.6)},
    )
    options = PlannerSpec(seed=0, time_limit=20.0)
    plan = plan_mission(world, "<>a", np.array(START[:2]), 0.4, options)
    return world, plan


def test_the_guide_backs_into_the_hall_before_it_drives_to_the_goal() -> None:
    world, plan = lane()
    rho = FACTOR * robot_params("racecar").min_turning_radius()
    steps = clearances(RADIUS, plan.hold)
    (drawn,) = redraw_course(world, plan.subtasks, Pose(np.array(START[:2]), math.pi), rho, steps)
    assert drawn.reverse > 0
    lead = drawn.path[: drawn.reverse + 1]
    assert lead[1, 0] > lead[0, 0]  # facing west, moving east: backing up
    assert lead[:, 1].max() > 2.8  # into the hall
    assert not world.in_collision(drawn.path, RADIUS).any()


def test_the_pursuit_feedforward_alone_makes_the_three_point_turn() -> None:
    world, plan = lane()
    mission = Mission(Prebuilt(world), RobotSpec(model="racecar", start=START, radius=RADIUS))
    options: dict[str, Any] = {
        "drivable_guide": FACTOR,
        "guide_feedforward": 1.0,
        "min_forward": 0.2,
    }
    env = make_env(mission, 0, "rrt", world=world, plan=plan, feedforward_law="pursuit", **options)
    try:
        for seed in range(3):
            env.reset(seed=seed)
            info: dict[str, object] = {}
            backed = False
            for _ in range(env.max_steps):
                _, _, done, cut, info = env.step(np.zeros(2, dtype=np.float32))
                backed = backed or env.robot.position()[1] > 2.8
                if done or cut:
                    break
            assert info["is_success"], info
            assert backed
        lead = env.legs[0]
        # a curriculum start on the lead faces back along it, as the car does there
        assert math.cos(lead.headings[0] - math.pi) > 0.9
        assert math.cos(lead.headings[-1]) > 0.9  # the last ball, in the lane, faces east
    finally:
        env.close()
