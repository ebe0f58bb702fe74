"""Seeded random missions for the planner benchmark: forests, mazes, rooms with doors, towers.

Each generator returns a mission document (the schema of ``examples/*.yaml``) for one seeded
``numpy.random.Generator``: a 10 to 60 m world, a robot start and 3 to 12 goal discs or spheres
placed in free space, and a finite (visit all, in any order or in sequence) or infinite (patrol)
task. A goal that a grid search shows enclosed by obstacles is drawn again, so every mission
has a plan; the planner still has to find it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from planner.geometry.world import World
from planner.geometry.world_spec import WorldSpec
from planner.search.reachability import unreachable_regions
from workers.mission import MissionSpec, parse_mission

Document = dict[str, Any]
RADIUS = 0.2
"""Robot radius of every generated mission."""
WALL = 0.2
"""Thickness of maze and room walls."""


def _box(lo: list[float], hi: list[float]) -> Document:
    return {"box": {"min": [round(v, 3) for v in lo], "max": [round(v, 3) for v in hi]}}


def _ball(center: np.ndarray, radius: float) -> Document:
    return {"ball": {"center": [round(float(v), 3) for v in center], "radius": round(radius, 3)}}


def forest(rng: np.random.Generator) -> tuple[list[float], list[Document]]:
    """A square 2D world of 10 to 60 m strewn with balls (trees) covering about 15 %."""
    size = float(rng.uniform(10, 60))
    radii = rng.uniform(0.3, 1.5, size=int(0.15 * size * size / (np.pi * 0.75**2)) + 1)
    centres = rng.uniform(0, size, size=(len(radii), 2))
    return [size, size], [_ball(c, float(r)) for c, r in zip(centres, radii, strict=True)]


def maze(
    rng: np.random.Generator,
    n: int | None = None,
    cell: float | None = None,
    wall: float = WALL,
) -> tuple[list[float], list[Document]]:
    """A perfect maze (randomised depth-first search) of n x n cells (4 to 8 unless given),
    2.5 to 5 m each unless given, walls ``wall`` thick."""
    n = int(rng.integers(4, 9)) if n is None else n
    cell = float(rng.uniform(2.5, 5.0)) if cell is None else cell
    size = n * cell
    open_walls: set[tuple[int, int, int, int]] = set()
    seen = {(0, 0)}
    stack = [(0, 0)]
    while stack:
        i, j = stack[-1]
        nbrs = [
            (i + di, j + dj)
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))
            if 0 <= i + di < n and 0 <= j + dj < n and (i + di, j + dj) not in seen
        ]
        if not nbrs:
            stack.pop()
            continue
        k = nbrs[int(rng.integers(len(nbrs)))]
        open_walls.add((min(i, k[0]), min(j, k[1]), max(i, k[0]), max(j, k[1])))
        seen.add(k)
        stack.append(k)
    walls = []
    for i in range(n):
        for j in range(n):
            if i + 1 < n and (i, j, i + 1, j) not in open_walls:  # wall between columns i, i+1
                x = (i + 1) * cell
                walls.append(_box([x - wall / 2, j * cell], [x + wall / 2, (j + 1) * cell]))
            if j + 1 < n and (i, j, i, j + 1) not in open_walls:
                y = (j + 1) * cell
                walls.append(_box([i * cell, y - wall / 2], [(i + 1) * cell, y + wall / 2]))
    return [size, size], walls


def rooms(rng: np.random.Generator) -> tuple[list[float], list[Document]]:
    """A grid of k x k rooms, every inner wall pierced by one door 0.7 to 1.5 m wide."""
    k = int(rng.integers(2, 5))
    room = float(rng.uniform(5, 15))
    size = k * room
    walls = []
    for axis in (0, 1):
        for line in range(1, k):
            c = line * room
            for seg in range(k):
                door = float(rng.uniform(0.7, 1.5))
                at = seg * room + float(rng.uniform(1.0, room - 1.0 - door))
                for lo, hi in ((seg * room, at), (at + door, (seg + 1) * room)):
                    if hi - lo > 1e-6:
                        a, b = [c - WALL / 2, lo], [c + WALL / 2, hi]
                        walls.append(_box(a, b) if axis == 0 else _box(a[::-1], b[::-1]))
    return [size, size], walls


def towers(rng: np.random.Generator) -> tuple[list[float], list[Document]]:
    """A 3D city block: 10 to 60 m square, 10 m high, towers of random footprint and height."""
    size = float(rng.uniform(10, 60))
    count = int(0.12 * size * size / 9.0) + 1
    return [size, size, 10.0], scattered_boxes(rng, size, count, (1.0, 4.0), (2.0, 9.0))


def scattered_boxes(
    rng: np.random.Generator,
    size: float,
    count: int,
    sides: tuple[float, float],
    heights: tuple[float, float] | None = None,
) -> list[Document]:
    """``count`` boxes of footprint sides drawn from ``sides`` placed at random in a square of
    ``size``; with ``heights``, standing on the ground (3D) to a height drawn from it."""
    out = []
    for _ in range(count):
        w = rng.uniform(*sides, size=2)
        lo = rng.uniform(0, size - w)
        if heights is None:
            out.append(_box(lo.tolist(), (lo + w).tolist()))
        else:
            h = float(rng.uniform(*heights))
            out.append(_box([*lo.tolist(), 0.0], [*(lo + w).tolist(), h]))
    return out


KINDS: dict[str, Callable[[np.random.Generator], tuple[list[float], list[Document]]]] = {
    "forest": forest,
    "maze": maze,
    "rooms": rooms,
    "towers": towers,
}


def _task(rng: np.random.Generator, goals: int, infinite: bool) -> str:
    names = [f"g{i + 1}" for i in range(goals)]
    if infinite:
        return "[]!obstacle && " + " && ".join(f"[]<>{g}" for g in names)
    if rng.random() < 0.5:
        return "[]!obstacle && " + " && ".join(f"<>{g}" for g in names)
    nested = names[-1]
    for g in reversed(names[:-1]):
        nested = f"{g} && <>({nested})"
    return f"[]!obstacle && <>({nested})"


GOAL_DRAWS = 200
"""Draws per goal before a crowded world keeps the goals that fit (at least 3)."""


def _free_point(world: World, rng: np.random.Generator, clearance: float) -> np.ndarray:
    return np.asarray(world.sample_free(rng, 1, clearance)[0])


def random_mission(kind: str, seed: int, infinite: bool, goals: int | None = None) -> Document:
    """A mission of world kind ``kind`` for ``seed``; 3 to 12 goals unless ``goals`` is given
    (fewer when no more fit: ``GOAL_DRAWS``)."""
    rng = np.random.default_rng(seed)
    extent, obstacles = KINDS[kind](rng)
    dim = len(extent)
    count = goals if goals is not None else int(rng.integers(3, 13))
    bounds = [[0.0, round(e, 3)] for e in extent]
    base: Document = {"bounds": bounds, "obstacles": obstacles, "regions": {}}
    world = WorldSpec.model_validate(base).build()
    goal_r = 0.5 if dim == 3 else 1.0
    start = _free_point(world, rng, RADIUS + 0.3)
    regions: Document = {}
    for _ in range(GOAL_DRAWS * count):
        if len(regions) == count:
            break
        c = _free_point(world, rng, goal_r + RADIUS)
        others = [np.array(r["ball"]["center"]) for r in regions.values()]
        if np.linalg.norm(c - start) < 2 * goal_r + 1 or any(
            np.linalg.norm(c - o) < 2 * goal_r + 0.5 for o in others
        ):
            continue
        name = f"g{len(regions) + 1}"
        trial = {**regions, name: _ball(c, goal_r)}
        w = WorldSpec.model_validate({**base, "regions": trial}).build()
        if not unreachable_regions(w, start, RADIUS, [name]):
            regions = trial
    if len(regions) < 3:
        raise ValueError(f"{kind} world of seed {seed}: only {len(regions)} goals fit")
    task = _task(rng, len(regions), infinite)
    return _document(kind, seed, {**base, "regions": regions}, start.tolist(), task)


def _document(kind: str, seed: int, world: Document, start: list[float], task: str) -> Document:
    dim = len(world["bounds"])
    robot = (
        {"model": "quadrotor", "start": [round(v, 3) for v in start], "radius": RADIUS}
        if dim == 3
        else {"model": "unicycle", "start": [*(round(v, 3) for v in start), 0.0], "radius": RADIUS}
    )
    return {
        "name": f"random-{kind}-{seed}",
        "task": task,
        "robot": robot,
        "planner": {"seed": 0},
        "world": world,
    }


def suite(count: int, seed: int = 0) -> list[MissionSpec]:
    """``count`` missions cycling through the world kinds and finite / infinite tasks."""
    kinds = list(KINDS)
    out = []
    for i in range(count):
        doc = random_mission(
            kinds[i % len(kinds)], seed * 1000 + i, infinite=(i // len(kinds)) % 2 == 0
        )
        out.append(parse_mission(doc))
    return out
