"""TL-RRT* lassos on small worlds: validity, finite and infinite tasks, failures, determinism."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner.errors import PlanningError
from planner.geometry.labels import LabelOracle
from planner.geometry.polyline import path_length
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World
from planner.ltl.formula import parse
from planner.ltl.semantics import holds_on_lasso
from planner.ltl.translate import translate
from planner.search.planner_spec import PlannerSpec
from planner.search.tl_rrt_star import Lasso, plan_lasso


def world_2d() -> World:
    """10 x 10 with a wall in the middle (a gap at the top) and four goal regions."""
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [Box(np.array([4.5, 0.0]), np.array([5.5, 7.0])), Ball(np.array([2.0, 5.0]), 0.8)],
        {
            "a": Box(np.array([0.5, 8.0]), np.array([2.0, 9.5])),
            "b": Ball(np.array([8.5, 1.5]), 1.0),
            "c": Polygon(np.array([[7.0, 8.0], [9.5, 8.0], [7.0, 9.8]])),
            "d": Box(np.array([1.0, 1.0]), np.array([2.5, 2.5])),
        },
    )


def word(world: World, points: np.ndarray) -> list[frozenset[str]]:
    """Labels met along a polyline, densely sampled, stutters removed."""
    out = [world.labels(points[0])]
    for a, b in itertools.pairwise(points):
        pts = a + np.linspace(0.0, 1.0, 400)[1:, None] * (b - a)
        member = world.label_matrix(pts)
        for row in member:
            lab = frozenset(n for n, m in zip(world.region_names, row, strict=True) if m)
            if lab != out[-1]:
                out.append(lab)
    return out


def assert_valid(world: World, task: str, lasso: Lasso, start: np.ndarray, clr: float) -> None:
    pre, suf = lasso.prefix, lasso.suffix
    np.testing.assert_allclose(pre[0], start)
    np.testing.assert_allclose(suf[0], pre[-1])
    np.testing.assert_allclose(suf[-1], pre[-1])
    assert len(lasso.prefix_states) == len(pre) and len(lasso.suffix_states) == len(suf)
    for path in (pre, suf):
        assert not world.in_collision(path, clr).any()
        assert not world.in_collision(path, 0.0).any()
        if len(path) > 1:
            assert world.segments_free(path[:-1], path[1:], clr).all()
            assert (world.segments_label_changes(path[:-1], path[1:]) <= 1).all()
    assert lasso.prefix_cost == pytest.approx(path_length(pre))
    assert lasso.suffix_cost == pytest.approx(path_length(suf))
    assert lasso.cost == pytest.approx(0.2 * lasso.prefix_cost + 0.8 * lasso.suffix_cost)
    prefix_word = word(world, pre)
    cycle = word(world, suf)[1:] if len(suf) > 1 else [prefix_word[-1]]
    cycle = cycle or [prefix_word[-1]]
    assert translate(task).accepts_lasso(prefix_word, cycle)
    assert holds_on_lasso(parse(task), prefix_word, cycle)


START = np.array([1.0, 4.0])
FAST = {"refine_seconds": 0.0, "shortcut": False}


@pytest.mark.parametrize(
    "task",
    [
        "[]!obstacle && []<>a && []<>b && []<>c",
        "[]<>(b && <>(c && <>d)) && []!a",
        "<>a && []<>(c && <>b) && (!b U d)",
    ],
)
def test_infinite_tasks_give_valid_cycles(task: str) -> None:
    world = world_2d()
    lasso = plan_lasso(world, translate(task), START, 0.1, PlannerSpec(seed=1, **FAST))
    assert len(lasso.suffix) >= 3 and lasso.suffix_cost > 0
    assert_valid(world, task, lasso, START, 0.1)


def test_finite_task_has_trivial_suffix_and_refinement_helps() -> None:
    world = world_2d()
    task = "[]!obstacle && <>(b && <>(c && <>a))"
    nba = translate(task)
    first = plan_lasso(world, nba, START, 0.1, PlannerSpec(seed=2, **FAST))
    assert len(first.suffix) == 1 and first.suffix_cost == 0.0
    assert_valid(world, task, first, START, 0.1)
    better = plan_lasso(world, nba, START, 0.1, PlannerSpec(seed=2, refine_seconds=0.3))
    assert_valid(world, task, better, START, 0.1)
    assert better.cost < first.cost
    assert better.stats["first_cost"] == pytest.approx(first.cost)


def test_shortcut_keeps_cycle_valid_and_is_cheaper_in_3d() -> None:
    world = World(
        np.array([[0.0, 5.0], [0.0, 5.0], [0.0, 5.0]]),
        [Box(np.array([2.0, 0.0, 0.0]), np.array([3.0, 4.0, 5.0]))],
        {
            "g1": Ball(np.array([4.2, 1.0, 2.5]), 0.5),
            "g2": Box(np.array([0.5, 3.5, 3.5]), np.array([1.5, 4.5, 4.5])),
        },
    )
    task = "[]!obstacle && []<>g1 && []<>g2"
    start = np.array([0.5, 0.5, 0.5])
    nba = translate(task)
    raw = plan_lasso(world, nba, start, 0.2, PlannerSpec(seed=0, **FAST))
    polished = plan_lasso(world, nba, start, 0.2, PlannerSpec(seed=0, refine_seconds=0.0))
    assert_valid(world, task, polished, start, 0.2)
    assert polished.cost < raw.cost
    # every cycle crosses the wall between x = 1.5 (g2) and x = 3.7 (g1) twice
    assert polished.suffix_cost > 2 * (3.7 - 1.5)


def test_deterministic_per_seed() -> None:
    world = world_2d()
    nba = translate("[]<>a && []<>b")
    runs = [plan_lasso(world, nba, START, 0.0, PlannerSpec(seed=s, **FAST)) for s in (5, 5, 6)]
    np.testing.assert_array_equal(runs[0].prefix, runs[1].prefix)
    np.testing.assert_array_equal(runs[0].suffix, runs[1].suffix)
    assert runs[0].prefix_states == runs[1].prefix_states
    assert not np.array_equal(runs[0].prefix, runs[2].prefix)
    anytime = PlannerSpec(seed=5, refine_iterations=150)
    a, b = (plan_lasso(world, nba, START, 0.0, anytime) for _ in range(2))
    np.testing.assert_array_equal(a.prefix, b.prefix)
    np.testing.assert_array_equal(a.suffix, b.suffix)
    assert a.cost < runs[0].cost


def test_unsatisfiable_tasks_raise_before_sampling() -> None:
    world = world_2d()
    with pytest.raises(PlanningError, match="unsatisfiable"):
        plan_lasso(world, translate("[]<>a && <>[]!a"), START, 0.0, PlannerSpec())
    # satisfiable formula, but a and b never overlap in this world
    with pytest.raises(PlanningError, match="unsatisfiable in this world"):
        plan_lasso(world, translate("<>(a && b)"), START, 0.0, PlannerSpec())
    with pytest.raises(PlanningError, match="obstacle"):
        plan_lasso(world, translate("<>obstacle"), START, 0.0, PlannerSpec())


def test_enclosed_goal_names_the_region() -> None:
    ring = [
        Box(np.array([6.0, 6.0]), np.array([9.0, 6.5])),
        Box(np.array([6.0, 8.5]), np.array([9.0, 9.0])),
        Box(np.array([6.0, 6.0]), np.array([6.5, 9.0])),
        Box(np.array([8.5, 6.0]), np.array([9.0, 9.0])),
    ]
    world = World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        ring,
        {"inside": Ball(np.array([7.5, 7.5]), 0.5), "out": Ball(np.array([2.0, 2.0]), 0.5)},
    )
    opts = PlannerSpec(max_iterations=400, time_limit=20.0)
    with pytest.raises(PlanningError, match="region inside was never entered") as err:
        plan_lasso(world, translate("<>out && <>inside"), START, 0.0, opts)
    assert "enclosed" in str(err.value)
    with pytest.raises(PlanningError, match="no accepting state reached"):
        plan_lasso(world, translate("[]<>inside && []<>out"), START, 0.0, opts)


def test_bad_start() -> None:
    world = world_2d()
    with pytest.raises(PlanningError, match="collision"):
        plan_lasso(world, translate("<>a"), np.array([5.0, 3.0]), 0.0, PlannerSpec())
    with pytest.raises(PlanningError, match="already violated"):
        plan_lasso(world, translate("[]!d && <>a"), np.array([2.0, 2.0]), 0.0, PlannerSpec())


def test_start_inside_goal_is_a_one_point_plan() -> None:
    world = world_2d()
    start = np.array([1.0, 9.0])
    lasso = plan_lasso(world, translate("<>a"), start, 0.0, PlannerSpec())
    assert len(lasso.prefix) == 1 and len(lasso.suffix) == 1 and lasso.cost == 0.0


def test_label_oracle_matches_world() -> None:
    world = world_2d()
    oracle = LabelOracle(world, ["a", "b", "c", "d", "obstacle"])
    assert oracle.names == ("a", "b", "c", "d")
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 10, size=(5000, 2))
    np.testing.assert_array_equal(oracle.membership(pts), world.label_matrix(pts))
    masks = oracle.masks(pts[:100])
    assert [oracle.label(m) for m in masks] == [world.labels(p) - {"obstacle"} for p in pts[:100]]
    a = rng.uniform(0, 10, size=(2000, 2))
    b = a + rng.normal(size=(2000, 2))
    free = world.segments_free(a, b, 0.0)
    np.testing.assert_array_equal(
        oracle.changes(a, b)[free], world.segments_label_changes(a, b)[free]
    )
    only_a = LabelOracle(world, ["a"])
    assert only_a.names == ("a",)
    assert only_a.changes(np.array([[0.0, 1.75]]), np.array([[3.0, 1.75]])).tolist() == [0]
