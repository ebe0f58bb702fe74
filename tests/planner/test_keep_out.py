"""Plans keep the clearance from regions the task forbids where the path passes them."""

from __future__ import annotations

import numpy as np
import pytest

from planner.geometry.shapes import Ball, Box
from planner.geometry.world import World
from planner.ltl.translate import translate
from planner.plan import MissionPlan, plan_mission, verify_plan
from planner.search.keep_out import forbidden_regions
from planner.search.planner_spec import PlannerSpec

CLEARANCE = 0.5
START = np.array([1.0, 5.0])
QUICK = PlannerSpec(seed=0)


def corridor() -> World:
    """A 10 x 10 m room: the straight way from the start to g1 passes 0.1 m below g2, and a
    wall below it leaves room to pass g2 at the clearance."""
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [Box(np.array([3.0, 0.0]), np.array([7.0, 3.0]))],
        {
            "g1": Ball(np.array([9.0, 5.0]), 0.8),
            "g2": Ball(np.array([5.0, 6.1]), 1.0),
        },
    )


def least_distance(plan: MissionPlan, region: str, world: World) -> float:
    path = np.asarray(plan.subtasks[0].path)
    t = np.linspace(0.0, 1.0, 200)
    dense = (path[:-1, None, :] + t[None, :, None] * (path[1:] - path[:-1])[:, None, :]).reshape(
        -1, 2
    )
    return float(world.regions[region].distance(dense).min())


def test_the_regions_forbidden_in_each_state() -> None:
    world = corridor()
    until = translate("!g2 U g1")
    forbidden = forbidden_regions(until, world, ["g1", "g2"], CLEARANCE)
    assert forbidden == {until.initial: ("g2",)}
    avoid = translate("[]!g2 && <>g1")
    assert all(
        regions == ("g2",)
        for regions in forbidden_regions(avoid, world, ["g1", "g2"], CLEARANCE).values()
    )
    assert set(forbidden_regions(avoid, world, ["g1", "g2"], CLEARANCE)) == set(
        range(avoid.num_states)
    )
    assert forbidden_regions(translate("<>g1 && <>g2"), world, ["g1", "g2"], CLEARANCE) == {}


@pytest.mark.parametrize("task", ["!g2 U g1", "[]!g2 && <>g1"])
def test_a_forbidden_region_is_passed_at_the_clearance(task: str) -> None:
    world = corridor()
    plan = plan_mission(world, task, START, CLEARANCE, QUICK)
    assert verify_plan(plan, world, CLEARANCE) == []
    assert least_distance(plan, "g2", world) >= CLEARANCE - 1e-3


def test_a_region_the_task_allows_is_passed_as_close_as_the_shortest_path_goes() -> None:
    world = corridor()
    plan = plan_mission(world, "<>g1", START, CLEARANCE, QUICK)
    assert least_distance(plan, "g2", world) < 0.2


def door() -> World:
    """Two 5 x 10 m rooms joined by a door 0.8 m wide at (5, 6.6): wide enough for a robot of
    radius 0.3, not for it with half of a 0.3 m margin (0.9 m)."""
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [Box(np.array([4.9, 0.0]), np.array([5.1, 6.2])), Box(np.array([4.9, 7.0]), [5.1, 10.0])],
        {"g1": Ball(np.array([8.5, 1.5]), 0.5)},
    )


def obstacle_gaps(plan: MissionPlan, world: World) -> np.ndarray:
    """The distance to the obstacles of 50 points on each segment of the lasso."""
    path = np.concatenate([plan.lasso.prefix, plan.lasso.suffix])
    t = np.linspace(0.0, 1.0, 50)
    dense = path[:-1, None, :] + t[None, :, None] * (path[1:] - path[:-1])[:, None, :]
    return world.obstacle_distance(dense.reshape(-1, 2))


def test_a_plan_that_could_not_keep_the_margin_keeps_what_room_there_is() -> None:
    world = door()
    start = np.array([1.5, 1.5])
    margin = QUICK.model_copy(update={"margin": 0.3})
    plan = plan_mission(world, "<>g1", start, 0.3, margin)
    assert plan.clearance == pytest.approx(0.3)  # the door takes the radius alone
    assert verify_plan(plan, world, 0.3) == []
    gaps = obstacle_gaps(plan, world)
    # Through the door's middle (0.4 m from each post), not around a post's corner at 0.3 m.
    assert gaps.min() >= 0.39
    tight = plan_mission(world, "<>g1", start, 0.3, QUICK)  # no margin asked: pulled tight
    assert obstacle_gaps(tight, world).min() < 0.31


def test_the_margin_is_kept_along_the_long_chords_of_a_fallen_back_plan() -> None:
    """After the narrow door of ``door()``, a 1.4 m door crossed on the slant: pulled tight, the
    plan's long chord grazes its post, and the push must see the post between its samples (at
    every 9th of a chord it went unseen: 0.31 m). The push is best effort: 0.55 m of 0.6 m."""
    world = World(
        np.array([[0.0, 20.0], [0.0, 10.0]]),
        [
            *door().obstacles,
            Box(np.array([11.9, 0.0]), np.array([12.1, 2.0])),
            Box(np.array([11.9, 3.4]), np.array([12.1, 10.0])),
        ],
        {"g1": Ball(np.array([18.5, 1.0]), 0.5)},
    )
    for seed in range(3):
        spec = QUICK.model_copy(update={"margin": 0.3, "seed": seed})
        plan = plan_mission(world, "<>g1", np.array([1.5, 1.5]), 0.3, spec)
        assert plan.clearance == pytest.approx(0.3)
        path = np.concatenate([plan.lasso.prefix, plan.lasso.suffix])
        t = np.linspace(0.0, 1.0, 2000)
        dense = path[:-1, None, :] + t[None, :, None] * (path[1:] - path[:-1])[:, None, :]
        beyond = dense.reshape(-1, 2)
        beyond = beyond[beyond[:, 0] > 7.0]  # past the narrow door, where the margin fits
        assert world.obstacle_distance(beyond).min() >= 0.55
