"""The planning pipeline end to end: plan_mission, its JSON document and verify_plan."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from planner.errors import FormulaError, PlanningError
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World
from planner.plan import MissionPlan, plan_mission, translate_task, verify_plan
from planner.search.planner_spec import PlannerSpec
from planner.search.tl_rrt_star import plan_lasso


def reference_world() -> World:
    """The 1 x 1 workspace of the reference TL-RRT* implementation (shared benchmarks)."""

    def tri(x: float, y: float) -> Polygon:
        return Polygon(np.array([[x, y], [x + 0.2, y], [x, y + 0.2]]))

    return World(
        np.array([[0.0, 1.0], [0.0, 1.0]]),
        [
            Box(np.array([0.3, 0.0]), np.array([0.7, 0.2])),
            Box(np.array([0.4, 0.7]), np.array([0.6, 1.0])),
        ],
        {
            "l1": tri(0.1, 0.7),
            "l2": tri(0.7, 0.7),
            "l3": tri(0.7, 0.3),
            "l4": tri(0.3, 0.3),
            "l5": tri(0.0, 0.1),
            "l6": tri(0.0, 0.4),
        },
    )


START = np.array([0.8, 0.1])
QUICK = PlannerSpec(seed=0)


@pytest.fixture(scope="module")
def gf3() -> MissionPlan:
    return plan_mission(reference_world(), "[]<>l1 && []<>l2 && []<>l3", START, 0.0, QUICK)


def test_infinite_task_plan_is_valid_and_serialises(gf3: MissionPlan) -> None:
    assert verify_plan(gf3, reference_world(), 0.0) == []
    doc = gf3.to_json()
    assert set(doc) == {
        "formula",
        "automaton",
        "prefix",
        "suffix",
        "cost",
        "prefix_cost",
        "suffix_cost",
        "subtasks",
        "clearance",
        "seconds",
    }
    assert doc["automaton"]["states"] == gf3.pruned.num_states
    assert doc["automaton"]["unpruned"]["states"] == gf3.nba.num_states
    assert doc["prefix"][0] == START.tolist()
    assert doc["suffix"][0] == doc["suffix"][-1] == doc["prefix"][-1]
    assert doc["cost"] == pytest.approx(0.2 * doc["prefix_cost"] + 0.8 * doc["suffix_cost"])
    goals = [s["goal"] for s in doc["subtasks"]]
    assert {"l1", "l2", "l3"} <= set(goals)
    phases = [s["phase"] for s in doc["subtasks"]]
    assert phases == sorted(phases) and "suffix" in phases
    assert all(s["r_ball"] == pytest.approx(gf3.eta / 2) for s in doc["subtasks"])
    assert gf3.eta == pytest.approx(np.sqrt(2) / 20)
    assert 0 < gf3.translation_seconds <= gf3.seconds == doc["seconds"]
    json.dumps(doc)
    # the anytime phase and the shortcut leave the reference's first solutions far behind
    assert gf3.lasso.cost < 1.5


def test_finite_task_and_options() -> None:
    world = reference_world()
    opts = PlannerSpec(seed=4, refine_seconds=0.0, r_ball=0.03, eta=0.05)
    plan = plan_mission(world, "[]!l5 && <>(l1 && <>(l4 && <>l2))", START, 0.0, opts)
    assert verify_plan(plan, world, 0.0) == []
    assert len(plan.lasso.suffix) == 1 and plan.lasso.suffix_cost == 0.0
    assert [s.goal for s in plan.subtasks] == ["l1", "l4", "l2"]
    assert plan.r_ball == 0.03 and plan.eta == 0.05
    assert all(s["r_ball"] == 0.03 for s in plan.to_json()["subtasks"])


def test_case1_with_clearance() -> None:
    world = reference_world()
    task = "<>l1 && []<>(l2 && <>l3) && (!l3 U l4) && []!l5"
    plan = plan_mission(world, task, START, 0.02, PlannerSpec(seed=1, refine_seconds=0.1))
    assert verify_plan(plan, world, 0.02) == []
    goals = [s.goal for s in plan.subtasks]
    assert goals.index("l4") < goals.index("l3")
    assert not world.in_collision(plan.lasso.prefix, 0.02).any()


def test_margin_keeps_the_guide_off_obstacles_and_falls_back_where_too_narrow() -> None:
    world = reference_world()
    task = "<>l1 && []<>(l2 && <>l3) && (!l3 U l4) && []!l5"
    opts = PlannerSpec(seed=1, refine_seconds=0.1, margin=0.01)
    plan = plan_mission(world, task, START, 0.02, opts)
    assert plan.clearance == pytest.approx(0.03) and plan.hold == pytest.approx(0.03)
    assert verify_plan(plan, world, 0.03) == []
    # a margin wider than every passage: the plan keeps the radius alone
    wide = plan_mission(world, task, START, 0.02, opts.model_copy(update={"margin": 5.0}))
    assert wide.clearance == pytest.approx(0.02)
    assert wide.hold == pytest.approx(5.02)  # what the plan sought where there is room
    assert verify_plan(wide, world, 0.02) == []


def test_a_door_too_narrow_for_the_margin_keeps_half_of_it() -> None:
    """A 0.6 m door: a 0.1 m robot with the 0.3 m margin needs 0.8 m, with half of it 0.5 m."""
    world = World(
        np.array([[0.0, 10.0], [0.0, 4.0]]),
        [
            Box(np.array([4.9, 0.0]), np.array([5.1, 1.7])),
            Box(np.array([4.9, 2.3]), np.array([5.1, 4.0])),
        ],
        {"left": Ball(np.array([1.0, 2.0]), 0.4), "right": Ball(np.array([9.0, 2.0]), 0.4)},
    )
    opts = PlannerSpec(seed=0, refine_iterations=200, margin=0.3)
    plan = plan_mission(world, "<>(left && <>right)", np.array([2.0, 1.0]), 0.1, opts)
    assert plan.clearance == pytest.approx(0.25) and plan.hold == pytest.approx(0.4)
    assert verify_plan(plan, world, 0.25) == []


def test_bad_tasks() -> None:
    world = reference_world()
    with pytest.raises(FormulaError):
        plan_mission(world, "[]<>(l1 &&", START, 0.0, QUICK)
    with pytest.raises(FormulaError):
        plan_mission(world, "X l1", START, 0.0, QUICK)
    with pytest.raises(PlanningError, match="contradiction"):
        plan_mission(world, "[]l1 && <>!l1", START, 0.0, QUICK)
    with pytest.raises(PlanningError, match="unsatisfiable in this world"):
        plan_mission(world, "[]<>(l1 && l2)", START, 0.0, QUICK)


def walled_world() -> World:
    return World(
        np.array([[0.0, 1.0], [0.0, 1.0]]),
        [Box(np.array([0.5, 0.0]), np.array([0.6, 1.0]))],
        {"left": Ball(np.array([0.2, 0.5]), 0.1), "right": Ball(np.array([0.8, 0.5]), 0.1)},
    )


def test_enclosed_goal_is_reported_before_sampling() -> None:
    opts = PlannerSpec(max_iterations=500, time_limit=20.0)
    with pytest.raises(PlanningError, match="region right cannot be reached"):
        plan_mission(walled_world(), "<>left && <>right", np.array([0.1, 0.1]), 0.0, opts)


def test_exhausted_budget_names_the_region_never_entered() -> None:
    world = walled_world()
    _, pruned = translate_task("<>left && <>right", world, 0.0)
    opts = PlannerSpec(max_iterations=500, time_limit=20.0)
    with pytest.raises(PlanningError, match="region right was never entered"):
        plan_lasso(world, pruned, np.array([0.1, 0.1]), 0.0, opts)


def corrupt(plan: MissionPlan) -> MissionPlan:
    return copy.deepcopy(plan)


def test_verify_plan_catches_broken_invariants(gf3: MissionPlan) -> None:
    world = reference_world()
    bad = corrupt(gf3)
    bad.start = np.array([0.9, 0.1])
    assert any("start" in p for p in verify_plan(bad, world, 0.0))

    bad = corrupt(gf3)
    bad.lasso.suffix[-1] += 0.01
    assert any("same point" in p for p in verify_plan(bad, world, 0.0))

    bad = corrupt(gf3)
    k = len(bad.lasso.prefix) // 2
    bad.lasso.prefix[k] = [0.5, 0.85]  # inside the upper obstacle
    problems = verify_plan(bad, world, 0.0)
    assert any("collision" in p for p in problems)

    bad = corrupt(gf3)
    bad.subtasks[0].goal = "l6"
    assert any("goal region l6" in p for p in verify_plan(bad, world, 0.0))

    bad = corrupt(gf3)
    bad.subtasks[-1].path = bad.subtasks[-1].path[:-1]
    assert any("chain" in p for p in verify_plan(bad, world, 0.0))

    # a cycle that skips l1: the label sequence no longer satisfies the task
    bad = corrupt(gf3)
    x = bad.lasso.prefix[-1]
    bad.lasso.suffix = np.array([x, [0.75, 0.6], x])
    problems = verify_plan(bad, world, 0.0)
    assert any("automaton rejects" in p for p in problems)
    assert any("does not satisfy" in p for p in problems)

    # a robot radius the plan was not made for
    assert any("collision" in p for p in verify_plan(gf3, world, 0.2))
