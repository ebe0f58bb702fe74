"""A sound proof that some regions cannot be reached from the start, on an occupancy grid.

TL-RRT* can only give up on a goal enclosed by obstacles once its budget is spent. This module
answers the question at once, soundly: a region it reports is unreachable for every path of a
robot of radius ``clearance`` (a region it does not report may still be unreachable).

The workspace bounds are cut into a grid of cubic cells. A cell is *blocked* only when every
point of it is in collision: the whole cell lies inside one obstacle inflated by the clearance,
or entirely outside the bounds shrunk by the clearance. Inflated boxes, balls and convex
polygons are convex, so a cell is inside one when all its corners are; a non-convex polygon
blocks a cell when the cell's circumscribed ball fits in the inflated polygon (the distance to
the polygon is 1-lipschitz). Corners must be inside by a small slack so that floating-point
rounding in :meth:`World.in_collision` can never call a point of a blocked cell free.

Every other cell is *possibly free*. A collision-free path never enters a blocked cell (closed
cells), and the possibly-free cells it crosses are connected when cells sharing a face, an
edge or a corner are neighbours; so every point reachable from the start lies in a cell of
the start's component. A region that meets no cell of that component is unreachable.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable

import numpy as np
from scipy import ndimage

from planner.errors import PlanningError
from planner.geometry.shapes import (
    Ball,
    BoolArray,
    Box,
    FloatArray,
    Polygon,
    Shape,
    box_sqdist,
    segment_point_sqdist,
)
from planner.geometry.world import World
from planner.ltl.automaton import Buchi
from planner.ltl.guard import Cube
from planner.ltl.prune import has_accepting_run, prune

MAX_CELLS = 250_000
"""Default grid size: the cell edge is chosen so the grid over the bounds has about this many."""

_PROBE = 256
"""Candidate cells tried first when looking for a component cell that meets a region."""

_REL_TOL = 1e-9
"""Slack, relative to the workspace's coordinate scale, by which a cell must be in collision."""


class CellGrid:
    """Cubic cells of edge ``h`` from ``lo``; cell ``k`` spans ``lo + h*k .. lo + h*(k+1)``."""

    def __init__(self, world: World, max_cells: int) -> None:
        if max_cells < 1:
            raise ValueError(f"max_cells must be at least 1, got {max_cells}")
        lo, hi = world.bounds[:, 0], world.bounds[:, 1]
        extent = hi - lo
        self.dim = world.dim
        self.lo = lo
        self.h = float((np.prod(extent) / max_cells) ** (1.0 / self.dim))
        self.shape = tuple(max(1, math.ceil(e / self.h)) for e in extent)
        self.half_diag = 0.5 * self.h * math.sqrt(self.dim)
        self.tol = _REL_TOL * max(1.0, float(np.abs(world.bounds).max()))

    def corner(self, axis: int, k: np.ndarray) -> FloatArray:
        """Coordinates of corner planes ``k`` along ``axis`` (also the cells' low faces)."""
        return np.asarray(self.lo[axis] + self.h * k.astype(float))

    def cells_touching(self, lo: FloatArray, hi: FloatArray) -> list[slice] | None:
        """Per axis, a slice of cells covering every cell that meets ``[lo, hi]`` (None: none).

        Generous by a cell on each side, so rounding cannot leave a meeting cell out.
        """
        out = []
        for j in range(self.dim):
            first = max(0, math.floor((lo[j] - self.lo[j]) / self.h) - 1)
            last = min(self.shape[j], math.floor((hi[j] - self.lo[j]) / self.h) + 2)
            if last <= first:
                return None
            out.append(slice(first, last))
        return out

    def points(self, index: list[slice], offset: float) -> FloatArray:
        """(n, d) points ``lo + h*(k + offset)`` over the index ranges (0: corners, 0.5: centres).

        For corners, each range is extended by one so the far corners are included.
        """
        axes = []
        for j, s in enumerate(index):
            k = np.arange(s.start, s.stop + 1 if offset == 0.0 else s.stop)
            axes.append(self.corner(j, k) + offset * self.h)
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def all_corners(self, inside: BoolArray) -> BoolArray:
        """Cells whose 2^d corners are all ``True`` in the corner array ``inside``."""
        out = np.ones(tuple(n - 1 for n in inside.shape), dtype=bool)
        for shift in itertools.product((0, 1), repeat=self.dim):
            out &= inside[tuple(slice(s, s + n) for s, n in zip(shift, out.shape, strict=True))]
        return out


def _is_convex(poly: Polygon) -> bool:
    v = poly.vertices
    e = np.roll(v, -1, axis=0) - v
    turn = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    return bool(np.all(turn >= 0.0) or np.all(turn <= 0.0))


def _edge_distance(poly: Polygon, p: FloatArray) -> FloatArray:
    v0, v1 = poly.vertices, np.roll(poly.vertices, -1, axis=0)
    return np.sqrt(segment_point_sqdist(v0, v1, p[:, None, :]).min(axis=1))


def _deep_inside(shape: Shape, p: FloatArray, margin: float) -> BoolArray:
    """Points whose signed distance to the convex ``shape`` is at most ``margin`` (which may be
    negative: then the points must lie that deep inside)."""
    if isinstance(shape, Box):
        if margin >= 0.0:
            return np.asarray(box_sqdist(p, shape.lo, shape.hi) <= margin * margin)
        return np.asarray(np.all((p >= shape.lo - margin) & (p <= shape.hi + margin), axis=1))
    if isinstance(shape, Ball):
        r = shape.radius + margin
        diff = p - shape.center
        return np.asarray((r >= 0.0) & ((diff * diff).sum(axis=1) <= r * r))
    edge = _edge_distance(shape, p)
    inside = shape.contains(p, 0.0)
    if margin > 0.0:
        return np.asarray(inside | (edge <= margin))
    return np.asarray(inside & (edge > -margin))


def _blocked(world: World, grid: CellGrid, clearance: float) -> BoolArray:
    """Cells entirely in collision for a robot of radius ``clearance``."""
    blocked = np.zeros(grid.shape, dtype=bool)
    inner_lo = world.bounds[:, 0] + clearance
    inner_hi = world.bounds[:, 1] - clearance
    for j in range(grid.dim):
        k = np.arange(grid.shape[j])
        outside = (grid.corner(j, k + 1) < inner_lo[j]) | (grid.corner(j, k) > inner_hi[j])
        index: list[slice | np.ndarray] = [slice(None)] * grid.dim
        index[j] = outside
        blocked[tuple(index)] = True
    margin = clearance - grid.tol
    for shape in world.obstacles:
        lo, hi = shape.bounding_box()
        cells = grid.cells_touching(lo - clearance, hi + clearance)
        if cells is None:
            continue
        if isinstance(shape, Polygon) and not _is_convex(shape):
            centres = grid.points(cells, 0.5)
            edge = _edge_distance(shape, centres)
            inside = shape.contains(centres, 0.0)
            reach = grid.half_diag + grid.tol
            full = np.where(inside, edge >= reach - clearance, edge + reach <= clearance)
            blocked[tuple(cells)] |= full.reshape(tuple(s.stop - s.start for s in cells))
            continue
        corners = grid.points(cells, 0.0)
        inside = _deep_inside(shape, corners, margin)
        inside = inside.reshape(tuple(s.stop - s.start + 1 for s in cells))
        blocked[tuple(cells)] |= grid.all_corners(inside)
        if isinstance(shape, Box):
            blocked[tuple(cells)] |= _box_slabs(grid, shape, clearance, cells)
    return blocked


def _box_slabs(grid: CellGrid, box: Box, clearance: float, cells: list[slice]) -> BoolArray:
    """Cells inside the box stretched by ``clearance`` along a single axis (the flat faces of
    the inflated box), with no slack: the comparisons mirror, operation for operation, the
    ones :meth:`World.in_collision` makes, and rounding is monotone, so no point of such a
    cell can be judged free. This keeps walls flush with the bounds closed at clearance 0."""
    within, stretched = [], []
    for j, s in enumerate(cells):
        k = np.arange(s.start, s.stop)
        c_lo, c_hi = grid.corner(j, k), grid.corner(j, k + 1)
        within.append((box.lo[j] <= c_lo) & (c_hi <= box.hi[j]))
        stretched.append((box.lo[j] - c_lo <= clearance) & (c_hi - box.hi[j] <= clearance))
    out = np.zeros(tuple(s.stop - s.start for s in cells), dtype=bool)
    for j in range(grid.dim):
        term = np.ones_like(out)
        for i in range(grid.dim):
            along = [1] * grid.dim
            along[i] = -1
            term &= (stretched[i] if i == j else within[i]).reshape(along)
        out |= term
    return out


def _start_component(grid: CellGrid, comp: np.ndarray, start: FloatArray) -> int:
    """Label of the possibly-free component holding ``start`` (0 when its cells are blocked)."""
    ranges = []
    for j in range(grid.dim):
        k0 = math.floor((start[j] - grid.lo[j]) / grid.h)
        ks = [k for k in (k0 - 1, k0, k0 + 1) if 0 <= k < grid.shape[j]]
        ranges.append(
            [
                k
                for k in ks
                if grid.corner(j, np.array(k)) <= start[j] <= grid.corner(j, np.array(k + 1))
            ]
        )
    for cell in itertools.product(*ranges):
        if comp[cell]:
            return int(comp[cell])
    return 0


def unreachable_regions(
    world: World,
    start: np.ndarray,
    clearance: float,
    labels: Iterable[str],
    max_cells: int = MAX_CELLS,
) -> list[str]:
    """The regions among ``labels`` that a robot of radius ``clearance`` provably cannot reach
    from ``start`` (sorted). Sound: a reachable region is never listed.

    Names that are not regions of ``world`` (such as ``"obstacle"``) are ignored. A start that
    is not a collision-free point of the workspace proves nothing: the result is then empty
    (the planner reports that start itself).
    """
    names = sorted({n for n in labels if n in world.regions})
    s = np.asarray(start, dtype=float).reshape(-1)
    if not names or s.shape != (world.dim,) or not np.all(np.isfinite(s)):
        return []
    if world.in_collision(s[None, :], clearance)[0]:
        return []
    grid = CellGrid(world, max_cells)
    free = ~_blocked(world, grid, clearance)
    comp, _ = ndimage.label(free, structure=np.ones((3,) * grid.dim, dtype=bool))
    home = _start_component(grid, comp, s)
    if home == 0:
        return []
    return [n for n in names if not _meets(grid, comp == home, world.regions[n])]


def _meets(grid: CellGrid, component: BoolArray, region: Shape) -> bool:
    """Whether some cell of ``component`` may meet ``region`` (conservatively: its centre is
    within half a cell diagonal of the region). A spread-out sample of the candidate cells is
    tried first: when the region is reachable it usually settles the question."""
    lo, hi = region.bounding_box()
    cells = grid.cells_touching(lo, hi)
    if cells is None:
        return False
    candidates = np.flatnonzero(component[tuple(cells)])
    if candidates.size == 0:
        return False
    centres = grid.points(cells, 0.5)
    reach = grid.half_diag + grid.tol
    if candidates.size > _PROBE:
        probe = candidates[np.linspace(0, candidates.size - 1, _PROBE).astype(int)]
        if np.any(region.distance(centres[probe]) <= reach):
            return True
    return bool(np.any(region.distance(centres[candidates]) <= reach))


def _without(nba: Buchi, regions: frozenset[str]) -> Buchi:
    """``nba`` without the transitions that need the robot inside one of ``regions``."""

    def possible(cube: Cube) -> bool:
        return not (cube.pos & regions)

    return prune(nba, possible)


def restrict_to_reachable(nba: Buchi, world: World, start: np.ndarray, clearance: float) -> Buchi:
    """``nba`` without the transitions into regions the robot cannot reach from ``start``.

    The result accepts the same runs the robot can realise, so TL-RRT* plans in it unchanged.
    PlanningError, at once, when every accepting run needs an unreachable region; the message
    names the regions that are needed (each alone, else all the unreachable ones).
    """
    unreachable = unreachable_regions(world, start, clearance, nba.atoms)
    if not unreachable:
        return nba
    reduced = _without(nba, frozenset(unreachable))
    if has_accepting_run(reduced):
        return reduced
    needed = [u for u in unreachable if not has_accepting_run(_without(nba, frozenset((u,))))]
    named = needed or unreachable
    if len(named) == 1:
        what, need = f"region {named[0]} cannot be reached from the start: it is", "it"
    else:
        what = f"regions {', '.join(named)} cannot be reached from the start: they are"
        need = "them" if needed else "one of them"
    raise PlanningError(
        f"{what} enclosed by obstacles (for a robot of radius {clearance:g}), and every "
        f"accepting run of the task needs {need}"
    )
