"""Geometric RRT* (Karaman and Frazzoli), as in the appendix of Cai et al. (RA-L 2023).

Each iteration samples a free point, steers from its nearest tree node by at most ``eta``,
keeps the new point only if that segment is collision free, connects it to the cheapest
collision-free parent among the nodes within ``min(kappa (log n / n)^(1/d), eta)``, and rewires
those neighbours through it when that shortens their path. The planner is anytime: ``run`` may
be called again to continue, and always reports the best path found so far.

Nodes live in growing numpy arrays. Neighbour queries use a scipy cKDTree over the older nodes,
rebuilt in batches, plus a brute-force scan of the nodes added since the last rebuild; this was
measured as fast as a hash grid up to 10k nodes and faster beyond, in any dimension.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from planner.errors import PlanningError
from planner.geometry.shapes import BoolArray, FloatArray, as_points
from planner.geometry.world import World

GoalPredicate = Callable[[FloatArray], BoolArray]

_SAMPLE_BATCH = 256


@dataclass(frozen=True)
class RRTStarResult:
    """Best path so far (start to goal, (k, d)) or None, its length (inf if none), tree size."""

    path: FloatArray | None
    cost: float
    nodes: int


class _NeighbourIndex:
    """Nearest and radius queries over a growing point array: KD-tree plus a scanned tail."""

    def __init__(self, points: Callable[[], FloatArray]) -> None:
        self._points = points
        self._tree: cKDTree | None = None
        self._built = 0

    def _tail(self, x: FloatArray) -> tuple[FloatArray, int]:
        pts = self._points()
        if len(pts) - self._built > max(256, self._built // 20):
            self._tree = cKDTree(pts)
            self._built = len(pts)
        diff = pts[self._built :] - x
        return np.einsum("ij,ij->i", diff, diff), self._built

    def nearest(self, x: FloatArray) -> tuple[int, float]:
        d2, offset = self._tail(x)
        best, dist = -1, math.inf
        if self._tree is not None:
            dist, best = self._tree.query(x)
        if d2.size:
            k = int(d2.argmin())
            if d2[k] < dist * dist:
                best, dist = offset + k, math.sqrt(float(d2[k]))
        return int(best), float(dist)

    def near(self, x: FloatArray, radius: float) -> np.ndarray:
        d2, offset = self._tail(x)
        found = np.flatnonzero(d2 <= radius * radius) + offset
        if self._tree is not None:
            found = np.concatenate([self._tree.query_ball_point(x, radius), found])
        return found.astype(int)


class RRTStar:
    """Anytime geometric RRT* from ``start`` to a goal region label or a vectorised predicate.

    ``goal_bias`` is the probability of sampling inside the goal region (only when the goal is a
    region label). ``kappa`` defaults to 1.1 times the asymptotic-optimality bound
    ``(2 (1 + 1/d) mu(X) / zeta_d)^(1/d)`` with ``mu(X)`` the workspace measure, as OMPL does.
    Deterministic for a given ``rng`` state and iteration count.
    """

    def __init__(
        self,
        world: World,
        start: FloatArray,
        goal: GoalPredicate | str,
        eta: float,
        clearance: float,
        rng: np.random.Generator,
        goal_bias: float = 0.05,
        kappa: float | None = None,
    ) -> None:
        if not (eta > 0.0 and math.isfinite(eta)):
            raise PlanningError(f"RRT* step eta must be a finite number > 0, got {eta}")
        if not 0.0 <= goal_bias <= 1.0:
            raise PlanningError(f"goal_bias must lie in [0, 1], got {goal_bias}")
        x0 = as_points(start, world.dim)[0]
        if world.in_collision(x0, clearance)[0]:
            raise PlanningError(f"start {x0.tolist()} is in collision (clearance {clearance})")
        self.world, self.eta, self.clearance, self.rng = world, float(eta), float(clearance), rng
        self.goal_bias = goal_bias
        self._goal_label: str | None = None
        if isinstance(goal, str):
            region = world.region(goal)
            self._goal_label = goal
            self._goal: GoalPredicate = region.contains
        else:
            self._goal = goal
        d = world.dim
        zeta = math.pi ** (d / 2) / math.gamma(d / 2 + 1)
        self.kappa = (
            kappa
            if kappa is not None
            else (1.1 * (2.0 * (1.0 + 1.0 / d) * world.volume / zeta) ** (1.0 / d))
        )
        cap = 1024
        self._x = np.empty((cap, d))
        self._cost = np.empty(cap)
        self._parent = np.empty(cap, dtype=int)
        self._children: list[list[int]] = [[]]
        self._x[0], self._cost[0], self._parent[0] = x0, 0.0, -1
        self._n = 1
        self._index = _NeighbourIndex(lambda: self._x[: self._n])
        self._goal_nodes: list[int] = [0] if bool(self._goal(x0[None, :])[0]) else []
        self._samples = np.empty((0, d))
        self.iterations = 0

    @property
    def positions(self) -> FloatArray:
        """(n, d) tree node positions (node 0 is the start); a read-only view."""
        view = self._x[: self._n]
        view.flags.writeable = False
        return view

    @property
    def parents(self) -> np.ndarray:
        """(n,) parent index of every node (-1 for the root)."""
        return self._parent[: self._n].copy()

    @property
    def costs(self) -> FloatArray:
        """(n,) path length from the start to every node through the tree."""
        return self._cost[: self._n].copy()

    def _next_sample(self) -> FloatArray:
        while not len(self._samples):
            lo = self.world.bounds[:, 0] + self.clearance
            hi = self.world.bounds[:, 1] - self.clearance
            pts = self.rng.uniform(lo, hi, size=(_SAMPLE_BATCH, self.world.dim))
            if self._goal_label is not None and self.goal_bias > 0.0:
                coins = self.rng.uniform(size=_SAMPLE_BATCH) < self.goal_bias
                k = int(coins.sum())
                if k:
                    pts[coins] = self.world.region(self._goal_label).sample(self.rng, k)
            self._samples = pts[~self.world.in_collision(pts, self.clearance)]
        x, self._samples = self._samples[0], self._samples[1:]
        return x

    def _add(self, x: FloatArray, parent: int, cost: float) -> int:
        if self._n == len(self._x):
            self._x = np.concatenate([self._x, np.empty_like(self._x)])
            self._cost = np.concatenate([self._cost, np.empty_like(self._cost)])
            self._parent = np.concatenate([self._parent, np.empty_like(self._parent)])
        i = self._n
        self._x[i], self._cost[i], self._parent[i] = x, cost, parent
        self._children.append([])
        self._children[parent].append(i)
        self._n += 1
        return i

    def _reparent(self, j: int, parent: int, cost: float) -> None:
        self._children[int(self._parent[j])].remove(j)
        self._children[parent].append(j)
        self._parent[j] = parent
        delta = cost - self._cost[j]
        subtree, stack = [j], [j]
        while stack:
            kids = self._children[stack.pop()]
            subtree.extend(kids)
            stack.extend(kids)
        self._cost[subtree] += delta

    def step(self) -> None:
        """One RRT* iteration: sample, steer, choose parent, rewire."""
        self.iterations += 1
        x_rand = self._next_sample()
        i_near, dist = self._index.nearest(x_rand)
        if dist == 0.0:
            return
        x_near = self._x[i_near]
        x_new = x_near + (x_rand - x_near) * min(1.0, self.eta / dist)
        n = self._n
        radius = min(self.kappa * (math.log(n) / n) ** (1.0 / self.world.dim), self.eta)
        near = self._index.near(x_new, radius)
        near = np.concatenate([[i_near], near[near != i_near]])
        pts = self._x[near]
        ends = np.empty_like(pts)
        ends[:] = x_new
        free = self.world.segments_free(pts, ends, self.clearance)
        if not free[0]:
            return
        near, diff = near[free], pts[free] - x_new
        dists = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        through = self._cost[near] + dists
        best = int(through.argmin())
        new = self._add(x_new, int(near[best]), float(through[best]))
        cost_new = float(through[best])
        better = np.flatnonzero(cost_new + dists < self._cost[near])
        for k in better:
            j = int(near[k])
            cost_j = cost_new + float(dists[k])
            if cost_j < self._cost[j]:
                self._reparent(j, new, cost_j)
        if bool(self._goal(x_new[None, :])[0]):
            self._goal_nodes.append(new)

    def run(self, iterations: int, cpu_seconds: float | None = None) -> RRTStarResult:
        """Run up to ``iterations`` more iterations (or until ``cpu_seconds`` of process time)."""
        deadline = None if cpu_seconds is None else time.process_time() + cpu_seconds
        for it in range(iterations):
            if deadline is not None and it % 16 == 0 and time.process_time() >= deadline:
                break
            self.step()
        return self.result()

    def result(self) -> RRTStarResult:
        """The best path found so far (costs reflect every rewiring done since)."""
        if not self._goal_nodes:
            return RRTStarResult(None, math.inf, self._n)
        goals = np.array(self._goal_nodes)
        g = int(goals[self._cost[goals].argmin()])
        chain = [g]
        while self._parent[chain[-1]] >= 0:
            chain.append(int(self._parent[chain[-1]]))
        path = self._x[chain[::-1]].copy()
        return RRTStarResult(path, float(self._cost[g]), self._n)
