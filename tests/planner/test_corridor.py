"""Corridors through narrow passages (planner/search/corridor.py): the grid's path goes through
the door, every segment laid passes the tree's own edge check, and TL-RRT* stuck behind a door
a few centimetres wider than the robot finds its way in a few hundred iterations."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import planner.plan as plan_module
import planner.search.growth as growth
from planner.errors import PlanningError
from planner.geometry.labels import LabelOracle
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World
from planner.ltl.guard import Cube
from planner.ltl.translate import translate
from planner.search.corridor import FreeGrid, lay, region_cells
from planner.search.planner_spec import PlannerSpec
from planner.search.product_tree import ProductTree
from planner.search.tl_rrt_star import plan_lasso

CLEARANCE = 0.3
DOOR = 0.63
"""A door 3 cm wider than the robot's 0.6 m, in a wall 2 m thick."""
START = np.array([1.0, 5.0])


def walled_world() -> World:
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [
            Box(np.array([4.0, 0.0]), np.array([6.0, 5.0 - DOOR / 2])),
            Box(np.array([4.0, 5.0 + DOOR / 2]), np.array([6.0, 10.0])),
        ],
        {"g": Ball(np.array([9.0, 5.0]), 0.8)},
    )


def test_the_corridor_goes_through_the_door_and_every_segment_passes_the_edge_check() -> None:
    world = walled_world()
    oracle = LabelOracle(world, ["g"])
    tree = ProductTree(world, oracle, lambda q, mask: (0,), 1, CLEARANCE, eta=1.0, gamma=5.0)
    root = tree.add_point(START, 0)
    tree.add_node(root, 0, -1, 0.0)
    grid = FreeGrid(world, CLEARANCE)

    found = grid.path(grid.cells(START[None, :]), region_cells(grid, oracle, Cube.literal("g")))
    assert found is not None
    origin, centres = found
    assert origin == grid.cells(START[None, :])[0]
    assert oracle.membership(centres[-1:])[0, 0]  # it ends in the region
    inside_wall = centres[(centres[:, 0] > 4.0) & (centres[:, 0] < 6.0)]
    assert np.abs(inside_wall[:, 1] - 5.0).max() <= DOOR / 2 - CLEARANCE + grid.h

    added = lay(tree, root, centres, tree.eta)
    assert added >= 8  # 8 m from the start to the region, at most 1 m a segment
    u, v, _ = tree.roadmap.edges()
    assert len(u) == added
    assert tree.edges_ok(tree.pos[u], tree.pos[v]).all()
    assert oracle.membership(tree.pos[tree.npts - 1 : tree.npts])[0, 0]


@pytest.mark.parametrize("dim", [2, 3])
def test_a_cell_is_free_exactly_when_its_centre_keeps_the_clearance(dim: int) -> None:
    rng = np.random.default_rng(dim)
    size = 20.0
    centres, radii = rng.uniform(0, size, (60, dim)), rng.uniform(0.2, 1.0, 60)
    balls = [Ball(c, r) for c, r in zip(centres, radii, strict=True)]
    boxes = [Box(c, c + rng.uniform(0.2, 2.0, dim)) for c in rng.uniform(0, size - 2, (60, dim))]
    shapes: list[Ball | Box | Polygon] = [*balls, *boxes]
    if dim == 2:  # a non-convex one too
        arrow = np.array([[2.0, 2.0], [8.0, 2.0], [8.0, 8.0], [5.0, 4.0], [2.0, 8.0]])
        shapes.append(Polygon(arrow))
    world = World(np.array([[0.0, size]] * dim), shapes, {})

    grid = FreeGrid(world, CLEARANCE, max_cells=40_000)

    np.testing.assert_array_equal(grid.free, ~world.in_collision(grid.centres, CLEARANCE))


def test_a_wall_without_a_door_gives_no_corridor() -> None:
    world = World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [Box(np.array([4.0, 0.0]), np.array([6.0, 10.0]))],
        {"g": Ball(np.array([9.0, 5.0]), 0.8)},
    )
    grid = FreeGrid(world, CLEARANCE)
    oracle = LabelOracle(world, ["g"])
    targets = region_cells(grid, oracle, Cube.literal("g"))
    assert targets.size > 0
    assert grid.path(grid.cells(START[None, :]), targets) is None
    assert region_cells(grid, oracle, Cube.literal("elsewhere")).size == 0


@pytest.mark.parametrize("seed", [2, 3])
def test_tl_rrt_star_behind_a_narrow_door_lays_a_corridor(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    world, nba = walled_world(), translate("[]!obstacle && <>g")
    options = PlannerSpec(seed=seed, refine_seconds=0.0, shortcut=False, max_iterations=20_000)

    with_corridor = plan_lasso(world, nba, START, CLEARANCE, options)
    monkeypatch.setattr(growth, "CORRIDOR_AFTER", 10**9)
    sampling_alone = plan_lasso(world, nba, START, CLEARANCE, options)

    assert with_corridor.stats["prefix_iterations"] <= growth.CORRIDOR_AFTER + 100
    assert sampling_alone.stats["prefix_iterations"] > 1000
    assert world.segments_free(with_corridor.prefix[:-1], with_corridor.prefix[1:], CLEARANCE).all()


def test_an_attempt_with_a_margin_gives_up_once_the_goal_is_cut_off_at_its_clearance(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A door of 0.96 m in a 30 x 30 m world: a robot of radius 0.2 passes it with half its
    0.3 m margin, not with all of it (1 m). The door's walls, inflated by 0.5 m, overlap in a
    band 4 cm high, thinner than a cell of the sound reachability proof (6 cm), which cannot
    close it, so the attempt with the whole margin used to spend its 10,000 iterations. Now it
    ends when the corridor grid (a row of cell centres lies in the band) finds the goal cut
    off, and the plan keeps half the margin."""
    below = 14.55  # the band 15.01-15.05 holds the cell centres at y = 15.03
    world = World(
        np.array([[0.0, 30.0], [0.0, 30.0]]),
        [
            Box(np.array([14.0, 0.0]), np.array([16.0, below])),
            Box(np.array([14.0, below + 0.96]), np.array([16.0, 30.0])),
        ],
        {"g": Ball(np.array([25.0, 15.0]), 1.0)},
    )
    endings: list[str] = []
    real = plan_module.plan_lasso

    def recorded(*args: Any, **kwargs: Any) -> Any:
        try:
            return real(*args, **kwargs)
        except PlanningError as error:
            endings.append(str(error))
            raise

    monkeypatch.setattr(plan_module, "plan_lasso", recorded)
    options = PlannerSpec(seed=0, margin=0.3, refine_iterations=0, shortcut=False)

    start = np.array([5.0, 15.0])
    plan = plan_module.plan_mission(world, "[]!obstacle && <>g", start, 0.2, options)

    assert plan.clearance == pytest.approx(0.35)
    assert len(endings) == 1 and "cut off at this clearance" in endings[0], endings
