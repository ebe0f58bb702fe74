"""Geometric RRT*: valid paths in clutter, anytime improvement, determinism, unreachable goals."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from planner.errors import PlanningError, WorldError
from planner.geometry.shapes import Ball, Box, Shape
from planner.geometry.world import World
from planner.search.rrt_star import RRTStar

START = np.array([-9.0, -9.0])
CLEARANCE = 0.2


def cluttered_world(seed: int = 3, count: int = 50) -> World:
    """20 x 20 world with random boxes that keep the start and goal corners clear."""
    rng = np.random.default_rng(seed)
    keep = np.array([[-9.0, -9.0], [9.0, 9.0]])
    obstacles: list[Shape] = []
    while len(obstacles) < count:
        centre, size = rng.uniform(-10, 10, 2), rng.uniform(0.6, 1.6, 2)
        box = Box(centre - size / 2, centre + size / 2)
        if not box.contains(keep, 1.5).any():
            obstacles.append(box)
    return World([[-10.0, 10.0], [-10.0, 10.0]], obstacles, {"goal": Ball([9.0, 9.0], 0.5)})


def check_path(world: World, path: np.ndarray, cost: float) -> None:
    assert np.array_equal(path[0], START)
    assert world.regions["goal"].contains(path[-1:])[0]
    assert np.all(world.segments_free(path[:-1], path[1:], CLEARANCE))
    assert cost == pytest.approx(float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()))
    assert cost >= float(np.linalg.norm(path[-1] - START))


def test_finds_a_collision_free_path_in_clutter() -> None:
    world = cluttered_world()
    planner = RRTStar(
        world, START, "goal", eta=1.0, clearance=CLEARANCE, rng=np.random.default_rng(0)
    )
    result = planner.run(2500)
    assert result.path is not None and result.nodes > 1000
    check_path(world, result.path, result.cost)
    straight = float(np.linalg.norm([18.0, 18.0])) - 0.5
    assert result.cost < 1.25 * straight
    # the tree itself: every edge is free and every cost is its parent's plus the edge length
    x, parent, cost = planner.positions, planner.parents, planner.costs
    assert parent[0] == -1 and cost[0] == 0.0
    child = np.arange(1, len(x))
    assert np.all(world.segments_free(x[parent[child]], x[child], CLEARANCE))
    edge = np.linalg.norm(x[child] - x[parent[child]], axis=1)
    np.testing.assert_allclose(cost[child], cost[parent[child]] + edge, atol=1e-9)
    assert np.all(edge <= 1.0 + 1e-9)


def test_anytime_cost_never_increases() -> None:
    world = cluttered_world()
    planner = RRTStar(world, START, "goal", 1.0, CLEARANCE, np.random.default_rng(1))
    costs = []
    for _ in range(5):
        result = planner.run(800)
        costs.append(result.cost)
        if result.path is not None:
            check_path(world, result.path, result.cost)
    assert math.isfinite(costs[-1])
    assert all(b <= a for a, b in itertools.pairwise(costs))
    assert costs[-1] < costs[[math.isfinite(c) for c in costs].index(True)]
    assert planner.iterations == 4000


def test_same_seed_same_tree() -> None:
    world = cluttered_world()
    runs = [RRTStar(world, START, "goal", 1.0, CLEARANCE, np.random.default_rng(7)) for _ in "ab"]
    first = runs[0].run(700)
    runs[0].run(300)
    second = runs[1].run(1000)
    assert second.path is not None and first.nodes < second.nodes
    again = runs[0].result()
    assert again.path is not None
    np.testing.assert_array_equal(again.path, second.path)
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    other = RRTStar(world, START, "goal", 1.0, CLEARANCE, np.random.default_rng(8))
    other.run(1000)
    assert not np.array_equal(other.positions[:100], runs[1].positions[:100])


def test_unreachable_goal_returns_none() -> None:
    walls: list[Shape] = [Box([6.0, 6.0], [10.0, 6.5]), Box([6.0, 6.0], [6.5, 10.0])]
    world = World([[-10.0, 10.0], [-10.0, 10.0]], walls, {"goal": Ball([9.0, 9.0], 0.5)})
    planner = RRTStar(world, START, "goal", 1.0, CLEARANCE, np.random.default_rng(0))
    result = planner.run(1500)
    assert result.path is None and result.cost == math.inf and result.nodes > 100


def test_goal_as_predicate_and_in_3d() -> None:
    obstacles: list[Shape] = [Box([4.0, 0.0, 0.0], [6.0, 8.0, 10.0]), Ball([2.0, 8.0, 5.0], 1.0)]
    world = World([[0.0, 10.0]] * 3, obstacles, {})
    start = np.array([1.0, 1.0, 1.0])

    def goal(points: np.ndarray) -> np.ndarray:
        return np.asarray(points[:, 0] >= 8.5)

    planner = RRTStar(world, start, goal, 1.5, 0.3, np.random.default_rng(2))
    result = planner.run(2000)
    assert result.path is not None
    assert result.path[-1, 0] >= 8.5
    assert np.all(world.segments_free(result.path[:-1], result.path[1:], 0.3))
    assert np.any(result.path[:, 1] > 8.0)  # it went around the wall


def test_start_inside_the_goal_is_a_zero_cost_path() -> None:
    world = cluttered_world()
    result = RRTStar(world, np.array([9.0, 9.0]), "goal", 1.0, 0.1, np.random.default_rng(0)).run(
        10
    )
    assert result.path is not None and result.cost == 0.0 and len(result.path) == 1


def test_bad_input_is_reported() -> None:
    world = cluttered_world()
    rng = np.random.default_rng(0)
    blocked = world.obstacles[0].sample(rng, 1)[0]
    with pytest.raises(PlanningError, match="in collision"):
        RRTStar(world, blocked, "goal", 1.0, 0.0, rng)
    with pytest.raises(PlanningError, match="eta"):
        RRTStar(world, START, "goal", 0.0, 0.0, rng)
    with pytest.raises(WorldError, match="no such region"):
        RRTStar(world, START, "elsewhere", 1.0, 0.0, rng)
