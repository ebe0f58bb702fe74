"""Regression guards for the missions that once took minutes to plan (issue 17).

The targets (a few CPU seconds) are shown by ``bench/planner.py``; these tests only assert a
generous bound, so that a return of the old behaviour (a narrow passage or a patrol's suffix
searched for 100 s) fails loudly, and check that the plans are valid.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import pytest

from planner.plan import plan_mission, verify_plan
from workers.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
GUARD_SECONDS = 30.0


@pytest.mark.parametrize(
    "mission",
    [
        ROOT / "bench" / "missions" / "two-rooms-door.yaml",
        ROOT / "examples" / "car-phi2-inf.yaml",
    ],
    ids=lambda p: p.stem,
)
def test_hard_missions_plan_in_seconds(mission: Path) -> None:
    spec = load_mission(mission)
    world = spec.build_world()
    began = time.process_time()
    plan = plan_mission(world, spec.task, spec.robot.position(), spec.robot.radius, spec.planner)
    seconds = time.process_time() - began
    assert verify_plan(plan, world, spec.robot.radius) == []
    assert seconds < GUARD_SECONDS
    assert len(plan.lasso.suffix) > 2  # patrols: a real cycle through both rooms / all goals


def test_two_rooms_cycle_goes_through_the_door() -> None:
    spec = load_mission(ROOT / "bench" / "missions" / "two-rooms-door.yaml")
    world = spec.build_world()
    plan = plan_mission(world, spec.task, spec.robot.position(), spec.robot.radius, spec.planner)
    suffix = plan.lasso.suffix
    crossings = [(a[0] - 10.0) * (b[0] - 10.0) < 0 for a, b in itertools.pairwise(suffix)]
    assert sum(crossings) >= 2 and sum(crossings) % 2 == 0  # out through the door and back
    for a, b in itertools.pairwise(suffix):
        if (a[0] - 10.0) * (b[0] - 10.0) < 0:
            y = a[1] + (b[1] - a[1]) * (10.0 - a[0]) / (b[0] - a[0])
            assert 9.65 + spec.robot.radius <= y <= 10.35 - spec.robot.radius
