"""Reachability: enclosed regions are reported at once, open ones never (soundness)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planner.errors import PlanningError
from planner.geometry.shapes import Ball, Box, Polygon, Shape
from planner.geometry.world import World
from planner.ltl.translate import translate
from planner.plan import plan_mission, verify_plan
from planner.search.planner_spec import PlannerSpec
from planner.search.reachability import restrict_to_reachable, unreachable_regions
from workers.mission import load_mission

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BOUNDS = np.array([[0.0, 10.0], [0.0, 10.0]])
START = np.array([1.0, 1.0])
QUICK = PlannerSpec(seed=0, refine_seconds=0.0, max_iterations=3000, time_limit=10.0)


def ring(lo: float, hi: float, wall: float, gap: float = 0.0) -> list[Shape]:
    """Four box walls around the square ``[lo, hi]^2`` (outer edge); with ``gap`` > 0 the left
    wall has an opening that wide centred on the square."""
    walls: list[Shape] = [
        Box([lo, lo], [hi, lo + wall]),
        Box([lo, hi - wall], [hi, hi]),
        Box([hi - wall, lo], [hi, hi]),
    ]
    if gap <= 0.0:
        return [*walls, Box([lo, lo], [lo + wall, hi])]
    mid = 0.5 * (lo + hi)
    return [
        *walls,
        Box([lo, lo], [lo + wall, mid - gap / 2]),
        Box([lo, mid + gap / 2], [lo + wall, hi]),
    ]


def ring_world(gap: float = 0.0) -> World:
    regions: dict[str, Shape] = {"a": Ball([7.5, 7.5], 0.5), "b": Ball([2.0, 8.0], 0.5)}
    regions["c"] = Box([8.0, 1.0], [9.0, 2.0])
    return World(BOUNDS, ring(6.0, 9.0, 0.5, gap), regions)


def test_enclosed_goal_fails_at_once_naming_the_region() -> None:
    world = ring_world()
    assert unreachable_regions(world, START, 0.2, ["a", "b", "c", "obstacle"]) == ["a"]
    t0 = time.process_time()
    with pytest.raises(PlanningError) as err:
        plan_mission(world, "[]!obstacle && <>b && <>a", START, 0.2, QUICK)
    assert time.process_time() - t0 < 1.0
    message = str(err.value)
    assert "region a cannot be reached from the start: it is enclosed by obstacles" in message
    assert "(for a robot of radius 0.2)" in message
    assert "region b" not in message


def test_the_needed_regions_are_named() -> None:
    world = World(
        BOUNDS,
        ring(6.0, 9.0, 0.5) + ring(0.0, 3.0, 0.5),
        {"a": Ball([7.5, 7.5], 0.5), "b": Ball([1.5, 1.5], 0.5), "c": Ball([2.0, 8.0], 0.5)},
    )
    start = np.array([5.0, 5.0])
    assert unreachable_regions(world, start, 0.1, world.region_names) == ["a", "b"]
    with pytest.raises(PlanningError, match="region a cannot be reached") as err:
        plan_mission(world, "<>a && (<>b || <>c)", start, 0.1, QUICK)
    assert "region b" not in str(err.value)
    with pytest.raises(
        PlanningError, match=r"regions a, b cannot be reached .* they are .* needs one of them"
    ):
        plan_mission(world, "<>a || <>b", start, 0.1, QUICK)


def test_disjunctive_task_plans_via_the_reachable_region() -> None:
    world = ring_world()
    plan = plan_mission(world, "[]!obstacle && (<>a || <>b)", START, 0.2, QUICK)
    assert verify_plan(plan, world, 0.2) == []
    assert [s.goal for s in plan.subtasks if s.goal] == ["b"]
    assert all("a" not in cube.pos for e in plan.pruned.edges for cube in e.guard.cubes)


@pytest.mark.parametrize("max_cells", [300, 1000, 4321, 250_000])
def test_narrow_open_passage_is_not_reported(max_cells: int) -> None:
    """A gap of 0.45 with clearance 0.2 leaves the robot 0.05 of room: far narrower than a grid
    cell at these sizes (0.58 .. 0.02), yet open."""
    world = ring_world(gap=0.45)
    assert unreachable_regions(world, START, 0.2, world.region_names, max_cells) == []


def test_passage_closed_by_the_clearance_is_found() -> None:
    world = ring_world(gap=0.45)
    assert unreachable_regions(world, START, 0.3, world.region_names) == ["a"]


def test_start_inside_the_enclosure() -> None:
    world = ring_world()
    inside = np.array([7.0, 7.0])
    assert unreachable_regions(world, inside, 0.2, world.region_names) == ["b", "c"]
    assert unreachable_regions(world, np.array([6.2, 7.0]), 0.2, ["a", "b"]) == []


def test_bounds_close_an_enclosure() -> None:
    """An L-shaped wall cuts off a corner together with the shrunk workspace bounds."""
    walls: list[Shape] = [Box([7.0, 7.0], [10.0, 7.4]), Box([7.0, 7.0], [7.4, 10.0])]
    world = World(BOUNDS, walls, {"corner": Box([8.5, 8.5], [9.5, 9.5])})
    assert unreachable_regions(world, START, 0.2, ["corner"]) == ["corner"]
    shorter: list[Shape] = [Box([7.0, 7.0], [9.5, 7.4]), Box([7.0, 7.0], [7.4, 10.0])]
    world = World(BOUNDS, shorter, {"corner": Box([8.5, 8.5], [9.5, 9.5])})
    assert unreachable_regions(world, START, 0.2, ["corner"]) == []
    assert unreachable_regions(world, START, 0.3, ["corner"]) == ["corner"]


def test_wall_flush_with_the_bounds_at_zero_clearance() -> None:
    unit = np.array([[0.0, 1.0], [0.0, 1.0]])
    wall = Box([0.5, 0.0], [0.6, 1.0])
    world = World(unit, [wall], {"left": Ball([0.2, 0.5], 0.1), "right": Ball([0.8, 0.5], 0.1)})
    start = np.array([0.1, 0.1])
    assert unreachable_regions(world, start, 0.0, world.region_names) == ["right"]
    short = World(unit, [Box([0.5, 0.0], [0.6, 0.999])], world.regions)
    for cells in (100, 250_000):
        assert unreachable_regions(short, start, 0.0, short.region_names, cells) == []


def test_non_convex_polygon_encloses_once_inflated() -> None:
    """A C-shaped polygon with a 0.3 wide mouth: closed for clearance 0.2, open for 0.1."""
    outline = [(4, 4), (8, 4), (8, 5.85), (7, 5.85), (7, 5), (5, 5), (5, 7), (7, 7), (7, 6.15)]
    c_shape = Polygon(np.array([*outline, (8, 6.15), (8, 8), (4, 8)], dtype=float))
    world = World(BOUNDS, [c_shape], {"pocket": Ball([6.0, 6.0], 0.4)})
    assert unreachable_regions(world, START, 0.2, ["pocket"]) == ["pocket"]
    assert unreachable_regions(world, START, 0.1, ["pocket"]) == []
    triangle = Polygon([[0.0, 6.0], [4.0, 10.0], [0.0, 10.0]])
    world = World(BOUNDS, [triangle], {"tip": Ball([0.3, 9.7], 0.2)})
    assert unreachable_regions(world, START, 0.0, ["tip"]) == ["tip"]


def test_ring_of_balls_encloses() -> None:
    angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    centres = np.array([5.0, 5.0]) + 2.0 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    world = World(BOUNDS, [Ball(c, 0.4) for c in centres], {"hub": Ball([5.0, 5.0], 0.5)})
    assert unreachable_regions(world, START, 0.0, ["hub"]) == ["hub"]
    small = World(BOUNDS, [Ball(c, 0.2) for c in centres], {"hub": Ball([5.0, 5.0], 0.5)})
    assert unreachable_regions(small, START, 0.05, ["hub"], max_cells=5000) == []
    assert unreachable_regions(small, START, 0.12, ["hub"]) == ["hub"]


def test_3d_enclosure() -> None:
    bounds = np.array([[0.0, 10.0]] * 3)
    lo, hi, t = 5.0, 9.0, 0.4
    shell: list[Shape] = []
    for axis in range(3):
        for side in (lo, hi - t):
            a, b = np.full(3, lo), np.full(3, hi)
            a[axis], b[axis] = side, side + t
            shell.append(Box(a, b))
    regions: dict[str, Shape] = {"inner": Ball([7.0, 7.0, 7.0], 0.5), "outer": Ball([2, 8, 2], 1)}
    world = World(bounds, shell, regions)
    start = np.array([1.0, 1.0, 1.0])
    assert unreachable_regions(world, start, 0.2, ["inner", "outer"]) == ["inner"]
    t0 = time.process_time()
    with pytest.raises(PlanningError, match="region inner cannot be reached"):
        plan_mission(world, "<>outer && <>inner", start, 0.2, QUICK)
    assert time.process_time() - t0 < 1.0
    holed = [
        *shell[:-1],
        Box([lo, lo, hi - t], [6.5, hi, hi]),
        Box([6.9, lo, hi - t], [hi, hi, hi]),
    ]
    world = World(bounds, holed, regions)
    assert unreachable_regions(world, start, 0.15, ["inner"], max_cells=2000) == []
    assert unreachable_regions(world, start, 0.3, ["inner"]) == ["inner"]


def test_start_in_collision_proves_nothing() -> None:
    world = ring_world()
    assert unreachable_regions(world, np.array([6.2, 6.2]), 0.0, world.region_names) == []
    assert unreachable_regions(world, np.array([0.1, 5.0]), 0.2, world.region_names) == []
    assert unreachable_regions(world, START, 0.2, ["nowhere", "obstacle"]) == []


def test_restrict_keeps_the_automaton_when_everything_is_reachable() -> None:
    world = ring_world(gap=1.0)
    nba = translate("<>a && []<>b")
    assert restrict_to_reachable(nba, world, START, 0.2) is nba
    reduced = restrict_to_reachable(translate("<>c || <>a"), ring_world(), START, 0.2)
    assert all("a" not in cube.pos for e in reduced.edges for cube in e.guard.cubes)


def random_world(rng: np.random.Generator) -> World:
    obstacles: list[Shape] = []
    for _ in range(int(rng.integers(6, 14))):
        kind = rng.integers(3)
        c = rng.uniform(0.5, 9.5, size=2)
        if kind == 0:
            obstacles.append(Box(c - rng.uniform(0.2, 2.0, 2), c + rng.uniform(0.2, 2.0, 2)))
        elif kind == 1:
            obstacles.append(Ball(c, float(rng.uniform(0.3, 1.5))))
        else:
            k = int(rng.integers(4, 9))
            angles = (np.arange(k) + rng.uniform(0.0, 0.8, size=k)) * (2 * np.pi / k)
            radii = rng.uniform(0.4, 2.0, size=angles.size)
            pts = c + np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
            obstacles.append(Polygon(pts))
    regions: dict[str, Shape] = {
        f"r{i}": Ball(rng.uniform(0.5, 9.5, size=2), float(rng.uniform(0.1, 0.6))) for i in range(8)
    }
    return World(BOUNDS, obstacles, regions)


def roadmap_reached(
    world: World, start: np.ndarray, clearance: float, rng: np.random.Generator
) -> set[str]:
    """Regions holding a node of a probabilistic roadmap connected to ``start``: an independent
    witness of reachability (every edge is checked collision free)."""
    pts = np.vstack([start, world.sample_free(rng, 2500, clearance)])
    pairs = cKDTree(pts).query_pairs(1.2, output_type="ndarray")
    pairs = pairs[world.segments_free(pts[pairs[:, 0]], pts[pairs[:, 1]], clearance)]
    parent = np.arange(len(pts))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = int(parent[i])
        return i

    for i, j in pairs:
        parent[find(int(i))] = find(int(j))
    home = find(0)
    linked = np.array([find(i) == home for i in range(len(pts))])
    rows = world.label_matrix(pts[linked])
    return {n for j, n in enumerate(world.region_names) if rows[:, j].any()}


@pytest.mark.parametrize("seed", range(6))
def test_never_reports_a_region_a_roadmap_reaches(seed: int) -> None:
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    clearance = float(rng.uniform(0.0, 0.3))
    start = world.sample_free(rng, 1, clearance)[0]
    reached = roadmap_reached(world, start, clearance, rng)
    assert reached
    for cells in (200, 3000, 250_000):
        reported = set(unreachable_regions(world, start, clearance, world.region_names, cells))
        assert not reported & reached


@pytest.mark.parametrize(
    "name", ["car-phi2-fin", "car-phi2-inf", "quad-phi1-fin", "quad-phi3-inf", "tlrrt-case1"]
)
def test_examples_are_unaffected_and_fast(name: str) -> None:
    spec = load_mission(EXAMPLES / f"{name}.yaml")
    world = spec.build_world()
    start, radius = spec.robot.position(), spec.robot.radius
    best = np.inf
    for _ in range(3):
        t0 = time.process_time()
        assert unreachable_regions(world, start, radius, world.region_names) == []
        best = min(best, time.process_time() - t0)
    assert best < 0.2  # about 13 ms (car) and 19 ms (quadrotor) on an idle core
    nba = translate(spec.task)
    assert restrict_to_reachable(nba, world, start, radius) is nba
