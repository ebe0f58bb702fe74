"""The two kinds of growing tree of TL-RRT*: a tree with its goal and its sampling policy.

:class:`Growth` is one product tree (:mod:`planner.search.product_tree`) with automaton distances
to its goal states and the biased sampling of the paper: with probability ``bias`` it extends,
from its nearest node in the automaton state closest to the goal, toward a point of the region
whose label enables the next transition on a shortest automaton path; otherwise toward a uniform
free point. A tree that comes no closer to its goal for a while lays a corridor of grid cells
to the next region (:mod:`planner.search.corridor`). :class:`SuffixGrowth` is the tree rooted
at an accepting prefix node ``(x*, q*)``, started from the prefix tree's roadmap
(:mod:`planner.search.roadmap`), whose goal is a node that steps back to ``(x*, q*)``: it
records those closing nodes and the cheapest cycle.
"""

from __future__ import annotations

import math

import numpy as np

from planner.ltl.guard import Cube
from planner.search.corridor import FreeGrid, lay, region_cells
from planner.search.product_sampling import Realisable, Sampler, Stepper
from planner.search.product_tree import ProductTree

FLOOD_EVERY = 150
"""Iterations between two floods of a tree's automaton states over its roadmap while no lasso
exists (at least; see :meth:`Growth.flood_if_due`)."""
FLOOD_GROWTH = 1.2
CORRIDOR_AFTER = 300
"""Iterations without a state closer to the goal before the tree seeks a corridor to the next
region through the free cells of a grid (:mod:`planner.search.corridor`)."""
CORRIDOR_STATES = 4
"""Automaton states that get corridors per call (each search costs a shortest path over the
grid: a tenth of a second)."""


class Growth:
    """One product tree with its goal (automaton distances) and sampling policy."""

    def __init__(
        self,
        tree: ProductTree,
        paths: Realisable,
        dist: dict[int, int],
        sampler: Sampler,
        bias: float,
        home: np.ndarray | None = None,
        grids: dict[float, FreeGrid] | None = None,
    ) -> None:
        self.tree = tree
        self.paths = paths
        self.dist = dist
        self.sampler = sampler
        self.rng = sampler.rng
        self.bias = bias
        self.home = home
        self.iterations = 0
        self.stall = 0
        self.goal_nodes: list[int] = []
        self.next_flood = FLOOD_EVERY
        self.grids = {} if grids is None else grids
        """Free-cell grids by clearance, built on first need and shared with suffix trees."""
        self.best_dist = math.inf
        self.progress_at = 0
        """Iteration at which the least automaton distance in the tree last fell."""
        self.corridor_tried: set[int] = set()
        self.cut_off = False
        """Whether the last corridors sought found every next region cut off from the tree on
        the grid (whose cells keep the clearance at their centre: a hint, not a proof)."""

    def closest_states(self) -> tuple[int, list[int]]:
        """Least automaton distance to the goal among the tree's states, and those states."""
        present = [q for q in self.tree.layers if q in self.dist]
        if not present:
            return -1, []
        dmin = min(self.dist[q] for q in present)
        return dmin, sorted(q for q in present if self.dist[q] == dmin)

    def _target(self) -> tuple[np.ndarray, int | None, bool]:
        """Sampling target, the automaton layer to extend from (None: any) and whether the
        target is goal-directed."""
        if self.rng.random() >= self.bias:
            return self.sampler.free(), None, False
        dmin, states = self.closest_states()
        if not states:
            return self.sampler.free(), None, False
        q = states[int(self.rng.integers(len(states)))]
        if dmin == 0 and self.home is None:
            return self.sampler.free(), None, False
        # Goal-directed steps that keep failing (the layer is stuck behind an obstacle) are
        # traded for exploration of the layer toward uniform points.
        explore = 0.25 + 0.65 * (1.0 - math.exp(-self.stall / 40.0))
        if self.rng.random() < explore:
            return self.sampler.free(), q, False
        if dmin == 0 and self.home is not None:
            return self.sampler.near(self.home, self.tree.eta), q, True
        cubes = self.paths.advancing_cubes(q, self.dist)
        if not cubes:
            return self.sampler.free(), q, False
        x = self.sampler.satisfying(cubes[int(self.rng.integers(len(cubes)))])
        return (self.sampler.free(), q, False) if x is None else (x, q, True)

    def flood_if_due(self) -> list[int]:
        """:meth:`flood` after FLOOD_EVERY iterations, or a fifth more than at the last flood
        (a flood costs time linear in the roadmap: spaced geometrically, floods cost amortised
        O(1) per iteration however long the search)."""
        if self.iterations < self.next_flood:
            return []
        self.next_flood = max(
            self.iterations + FLOOD_EVERY, math.ceil(self.iterations * FLOOD_GROWTH)
        )
        return self.flood()

    def corridor_if_stuck(self) -> list[int]:
        """After CORRIDOR_AFTER iterations in which no state came closer to the goal, lay a
        corridor (:mod:`planner.search.corridor`) from each closest state's points toward the
        regions that advance it, once per state, and flood; returns the new goal nodes."""
        dmin, states = self.closest_states()
        if dmin < self.best_dist:
            self.best_dist, self.progress_at = dmin, self.iterations
            return []
        if dmin <= 0 or self.iterations - self.progress_at < CORRIDOR_AFTER:
            return []
        self.progress_at = self.iterations
        # A few states per call: an any-order task has hundreds at the same distance.
        todo = [q for q in states if q not in self.corridor_tried][:CORRIDOR_STATES]
        cubes = [(q, cube) for q in todo for cube in self.paths.advancing_cubes(q, self.dist)]
        laid = [self._corridor(q, cube) for q, cube in cubes]
        self.corridor_tried.update(todo)
        self.cut_off = bool(laid) and all(n is None for n in laid)
        return self.flood() if any(laid) else []

    def _corridor(self, q: int, cube: Cube) -> int | None:
        """Lay the shortest free-cell corridor from the points of state ``q`` to a cell whose
        label satisfies ``cube``; returns the points added (None: no free cells join them)."""
        tree = self.tree
        grid = self.grids.get(tree.clearance)
        if grid is None:
            grid = self.grids[tree.clearance] = FreeGrid(tree.world, tree.clearance)
        pids = np.flatnonzero(tree.node_at[: tree.npts, q] >= 0)
        cells = grid.cells(tree.pos[pids])
        found = grid.path(cells, region_cells(grid, tree.oracle, cube))
        if found is None:
            return None if grid.free[cells].any() else 0
        origin, centres = found
        return lay(tree, int(pids[np.flatnonzero(cells == origin)[0]]), centres, tree.eta)

    def flood(self) -> list[int]:
        """Spread the tree's automaton states over its roadmap (:meth:`ProductTree.flood`);
        returns the new nodes that reach the goal."""
        new = self.tree.flood()
        hits = [n for n in new if self.dist.get(self.tree.node_q[n]) == 0]
        self.goal_nodes.extend(hits)
        return hits

    def step(self) -> list[int]:
        """One biased-or-uniform RRT* iteration; returns the new nodes that reach the goal."""
        self.iterations += 1
        target, layer, directed = self._target()
        new = self.tree.extend(target, layer)
        hits = [n for n in new if self.dist.get(self.tree.node_q[n]) == 0]
        self.goal_nodes.extend(hits)
        if directed:
            self.stall = 0 if new else self.stall + 1
        return hits


class SuffixGrowth(Growth):
    """Suffix tree rooted at prefix node ``(x*, q*)``; goal: nodes that step back to it."""

    def __init__(
        self,
        growth: Growth,
        prefix_node: int,
        stepper: Stepper,
        sampler: Sampler,
        bias: float,
        seed: bool = True,
    ) -> None:
        prefix = growth.tree
        self.prefix_node = prefix_node
        self.q_star = prefix.node_q[prefix_node]
        pid = prefix.node_pt[prefix_node]
        self.x_star = prefix.pos[pid].copy()
        self.mask_star = prefix.mask[pid]
        paths = growth.paths
        n = paths.nba.num_states
        closing = [q for q in range(n) if self.q_star in stepper(q, self.mask_star)]
        tree = ProductTree(
            prefix.world,
            prefix.oracle,
            stepper,
            n,
            prefix.clearance,
            prefix.eta,
            prefix.gamma,
            prefix.lift,
        )
        self.roadmap_points = prefix.npts
        """Size of the prefix tree when this tree was seeded from its roadmap."""
        if seed:
            seeded = tree.seed_from(prefix, pid, self.q_star)
        else:
            tree.add_node(tree.add_point(self.x_star, self.mask_star), self.q_star, -1, 0.0)
            seeded = []
        dist = paths.distances_to(closing)
        super().__init__(tree, paths, dist, sampler, bias, self.x_star, growth.grids)
        self.closers: list[tuple[int, float]] = []
        self._close([n for n in seeded if self.dist.get(tree.node_q[n]) == 0])

    def step(self) -> list[int]:
        hits = super().step()
        self._close(hits)
        return hits

    def flood(self) -> list[int]:
        hits = super().flood()
        self._close(hits)
        return hits

    def _close(self, hits: list[int]) -> None:
        """Record the nodes among ``hits`` (in closing states) with a valid edge back to x*."""
        tree = self.tree
        pids = sorted({tree.node_pt[n] for n in hits} - {0})  # point 0 is x* itself
        if not pids:
            return
        x = tree.pos[pids]
        ok = tree.edges_ok(x, np.broadcast_to(self.x_star, x.shape))
        length = np.linalg.norm(x - self.x_star, axis=1)
        closing = {p: float(n) for p, n, g in zip(pids, length, ok, strict=True) if g}
        self.closers.extend(
            (n, closing[tree.node_pt[n]]) for n in hits if tree.node_pt[n] in closing
        )

    def best_cycle(self) -> tuple[int, float] | None:
        """The closing node with the cheapest cycle and that cycle's length."""
        if not self.closers:
            return None
        cost = self.tree.cost
        n, length = min(self.closers, key=lambda c: cost[c[0]] + c[1])
        return n, cost[n] + length
