"""Corridors through narrow passages: a path of grid cells wholly free at the clearance, from the
points a tree holds to a region it has not reached, checked segment by segment.

TL-RRT* grows by sampling. A goal region behind passages barely wider than the robot plus its
margin is entered only when samples happen to line up through them: on the 12-goal car mission
(0.5 m clearance between boxes 1-1.2 m apart) one region took 4,000 of a plan's 5,000
iterations. A grid finds such passages at once: a shortest path over the cells whose centre keeps
the clearance (neighbours share a face, an edge or a corner), from the tree's cells to the
region's. The cells are only a guide (a cell whose whole square keeps the clearance would be
sound, but then passages a few centimetres wide, which the tree does thread, vanish from the
grid): the segments between the corridor's waypoints are checked exactly, like every edge of
the tree, and the corridor ends where one fails. The checked segments join the tree's roadmap
(:mod:`planner.search.roadmap`), and the automaton states reach them by a flood, like any other
explored point.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from planner.geometry.labels import LabelOracle
from planner.geometry.world import World
from planner.ltl.guard import Cube
from planner.search.product_tree import ProductTree
from planner.search.reachability import MAX_CELLS, CellGrid


class FreeGrid:
    """The cells of a :class:`~planner.search.reachability.CellGrid` over the bounds;
    ``free[k]``: the centre of cell k keeps ``clearance`` from the obstacles and the bounds."""

    def __init__(self, world: World, clearance: float, max_cells: int = MAX_CELLS) -> None:
        grid = CellGrid(world, max_cells)
        self.h, self.lo, self.shape = grid.h, grid.lo, grid.shape
        self.centres = grid.points([slice(0, n) for n in self.shape], 0.5)
        occupied = np.zeros(self.shape, dtype=bool)
        inner_lo = world.bounds[:, 0] + clearance
        inner_hi = world.bounds[:, 1] - clearance
        for j in range(world.dim):
            centre = grid.corner(j, np.arange(self.shape[j])) + 0.5 * self.h
            index: list[slice | np.ndarray] = [slice(None)] * world.dim
            index[j] = (centre < inner_lo[j]) | (centre > inner_hi[j])
            occupied[tuple(index)] = True
        for shape in world.obstacles:  # each obstacle tests only the cells near it
            lo, hi = shape.bounding_box()
            cells = grid.cells_touching(lo - clearance, hi + clearance)
            if cells is not None:
                inside = shape.contains(grid.points(cells, 0.5), clearance)
                occupied[tuple(cells)] |= inside.reshape([s.stop - s.start for s in cells])
        self.free = ~occupied.ravel()
        self._graph = self._free_graph()

    def _free_graph(self) -> csr_matrix:
        """Edges between neighbouring free cells, weighted by the distance of their centres."""
        grid = np.arange(self.free.size).reshape(self.shape)
        rows, cols, weights = [], [], []
        for offset in itertools.product((-1, 0, 1), repeat=len(self.shape)):
            if not any(offset) or offset < (0,) * len(offset):
                continue  # each undirected pair once: the offsets after zero in lexical order
            pairs = list(zip(offset, self.shape, strict=True))
            here = tuple(slice(max(0, -o), n - max(0, o)) for o, n in pairs)
            there = tuple(slice(max(0, o), n - max(0, -o)) for o, n in pairs)
            a, b = grid[here].ravel(), grid[there].ravel()
            both = self.free[a] & self.free[b]
            rows.append(a[both])
            cols.append(b[both])
            weights.append(np.full(int(both.sum()), self.h * math.sqrt(sum(map(abs, offset)))))
        n = self.free.size
        return csr_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        )

    def cells(self, points: np.ndarray) -> np.ndarray:
        """The flat index of the cell holding each point (clipped to the grid)."""
        k = np.floor((points - self.lo) / self.h).astype(np.int64)
        k = np.clip(k, 0, np.array(self.shape) - 1)
        return np.ravel_multi_index(tuple(k.T), self.shape)

    def path(self, sources: np.ndarray, targets: np.ndarray) -> tuple[int, np.ndarray] | None:
        """The shortest free-cell path from any of the cells ``sources`` to any of the cells
        ``targets``: the cell it starts from and the centres of its cells after that one; None
        when no free path joins them."""
        sources = np.unique(sources[self.free[sources]])
        targets = targets[self.free[targets]]
        if sources.size == 0 or targets.size == 0:
            return None
        dist, pred, origin = dijkstra(
            self._graph, directed=False, indices=sources, min_only=True, return_predecessors=True
        )
        end = targets[np.argmin(dist[targets])]
        if not np.isfinite(dist[end]):
            return None
        cells = [int(end)]
        while pred[cells[-1]] >= 0:
            cells.append(int(pred[cells[-1]]))
        cells.reverse()
        return int(origin[end]), self.centres[cells[1:]]


def region_cells(grid: FreeGrid, oracle: LabelOracle, cube: Cube) -> np.ndarray:
    """The free cells whose centre's label satisfies ``cube`` (empty when a name of its
    positive part is not a region of the world)."""
    if not cube.pos <= set(oracle.names):
        return np.empty(0, dtype=np.int64)
    free = np.flatnonzero(grid.free)
    member = oracle.membership(grid.centres[free])
    column = {name: i for i, name in enumerate(oracle.names)}
    ok = np.ones(free.size, dtype=bool)
    for name in cube.pos:
        ok &= member[:, column[name]]
    for name in cube.neg & set(oracle.names):
        ok &= ~member[:, column[name]]
    return free[ok]


def lay(tree: ProductTree, start: int, centres: np.ndarray, spacing: float) -> int:
    """Add a corridor to ``tree``'s roadmap from its point ``start`` along the cell centres
    ``centres``: each waypoint is the farthest centre at most ``spacing`` ahead whose segment
    from the last waypoint passes the tree's own edge check; returns the points added (the
    corridor ends early where no segment passes)."""
    last, at, added = start, -1, 0
    while at < len(centres) - 1:
        x = tree.pos[last]
        ahead = centres[at + 1 :]
        reach = np.linalg.norm(ahead - x, axis=1)
        candidates = np.flatnonzero(reach <= spacing)
        if candidates.size == 0:
            candidates = np.array([0])
        ok = tree.edges_ok(np.broadcast_to(x, (candidates.size, x.size)), ahead[candidates])
        if not ok.any():
            break
        k = int(candidates[np.flatnonzero(ok)[-1]])
        pid = tree.add_point(ahead[k], tree.oracle.masks(ahead[k][None, :])[0])
        tree.roadmap.record(pid, np.array([last]), reach[[k]])
        last, at, added = pid, at + 1 + k, added + 1
    return added
