"""Fixtures shared by the worker tests: the tiny mission and its plan, planned once per module."""

from __future__ import annotations

import pytest

from planner.plan import MissionPlan, plan_mission
from workers.mission import MissionSpec

from .missions import tiny_mission


@pytest.fixture(scope="module")
def mission() -> MissionSpec:
    return tiny_mission()


@pytest.fixture(scope="module")
def plan(mission: MissionSpec) -> MissionPlan:
    world = mission.build_world()
    return plan_mission(
        world, mission.task, mission.robot.position(), mission.robot.radius, mission.planner
    )
