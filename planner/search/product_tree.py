"""The RRT* tree of TL-RRT* over the product of the workspace and a Büchi automaton.

A product node is a pair ``(x, q)``: a workspace point and an automaton state. One geometric
point may carry several nodes (one per automaton state reached there). The product transition
``(x, q) -> (x', q')`` exists when the segment ``x``-``x'`` is collision free (with the robot's
clearance), the task label changes at most once along it, and ``q'`` is a successor of ``q`` under
the label of the target point ``L(x')``: the automaton reads the label of every point as it
arrives there. The root of a prefix tree has already read ``L(start)``, so the word of a path
``x_0 x_1 ... x_n`` is ``L(x_0) L(x_1) ... L(x_n)`` and its node states form an automaton run
over it. Because the label changes at most once per edge, the labels met along the continuous
path are a stuttering of that word, which a formula without ``X`` cannot tell apart.

Extension is the RRT* step lifted to the product: steer from the nearest point (of the whole
tree, or of one automaton layer for biased sampling) by at most ``eta``, check all segments to
the geometric neighbours at once, create ``(x_new, q')`` for every automaton state reachable
from a neighbour with its cheapest parent, then rewire neighbours through the new nodes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from planner.geometry.labels import LabelOracle
from planner.geometry.world import World

Successors = Callable[[int, int], tuple[int, ...]]


def edges_ok(
    world: World, oracle: LabelOracle, clearance: float, a: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """(n,) validity of product edges' geometry a[i]-b[i]: collision free with the clearance
    and at most one change of the task label along the segment."""
    ok = np.asarray(world.segments_free(a, b, clearance), dtype=bool).copy()
    idx = np.flatnonzero(ok)
    if idx.size:
        ok[idx] = oracle.changes(a[idx], b[idx]) <= 1
    return ok


class PointIndex:
    """Nearest and radius queries over a growing point set.

    A cKDTree covers the points present at its last rebuild; later points are scanned by brute
    force and the tree is rebuilt once that tail grows past an eighth of the total.
    """

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self._pts = np.empty((64, dim))
        self._ids = np.empty(64, dtype=np.int64)
        self.size = 0
        self._kd: cKDTree | None = None
        self._frozen = 0

    def add(self, pid: int, x: np.ndarray) -> None:
        """Insert point id ``pid`` at ``x``."""
        if self.size == len(self._ids):
            self._pts = np.concatenate([self._pts, np.empty_like(self._pts)])
            self._ids = np.concatenate([self._ids, np.empty_like(self._ids)])
        self._pts[self.size] = x
        self._ids[self.size] = pid
        self.size += 1
        if self.size - self._frozen > max(256, self.size // 8):
            self._kd = cKDTree(self._pts[: self.size])
            self._frozen = self.size

    def nearest(self, x: np.ndarray) -> tuple[int, float]:
        """Id of the point nearest to ``x`` and its distance."""
        best_i, best_d = -1, math.inf
        if self._kd is not None:
            d, i = self._kd.query(x)
            best_i, best_d = int(i), float(d)
        if self.size > self._frozen:
            diff = self._pts[self._frozen : self.size] - x
            d2 = np.einsum("ij,ij->i", diff, diff)
            j = int(np.argmin(d2))
            if d2[j] < best_d * best_d:
                best_i, best_d = self._frozen + j, math.sqrt(float(d2[j]))
        return int(self._ids[best_i]), best_d

    def within(self, x: np.ndarray, r: float) -> np.ndarray:
        """Ids of the points at distance <= r from ``x``."""
        parts = []
        if self._kd is not None:
            parts.append(np.asarray(self._kd.query_ball_point(x, r), dtype=np.int64))
        if self.size > self._frozen:
            diff = self._pts[self._frozen : self.size] - x
            d2 = np.einsum("ij,ij->i", diff, diff)
            parts.append(self._frozen + np.flatnonzero(d2 <= r * r))
        if not parts:
            return np.empty(0, dtype=np.int64)
        return np.asarray(self._ids[np.concatenate(parts)])


class ProductTree:
    """RRT* tree in the product space; see the module docstring for the transition relation.

    Node attributes live in Python lists (the inner loops are scalar); point coordinates in a
    numpy array grown by doubling. ``layer(q)`` indexes the points carrying a node in state q.
    """

    def __init__(
        self,
        world: World,
        oracle: LabelOracle,
        successors: Successors,
        clearance: float,
        eta: float,
        gamma: float,
    ) -> None:
        self.world = world
        self.oracle = oracle
        self.successors = successors
        self.clearance = clearance
        self.eta = eta
        self.gamma = gamma
        self.dim = world.dim
        self.pos = np.empty((256, self.dim))
        self.npts = 0
        self.mask: list[int] = []
        self.pt_nodes: list[list[int]] = []
        self.node_pt: list[int] = []
        self.node_q: list[int] = []
        self.parent: list[int] = []
        self.cost: list[float] = []
        self.children: list[list[int]] = []
        self.lookup: dict[tuple[int, int], int] = {}
        self.index = PointIndex(self.dim)
        self.layers: dict[int, PointIndex] = {}
        self.entered = 0
        """Union of the label masks of all points: the regions the tree has been in."""

    @property
    def num_nodes(self) -> int:
        return len(self.node_q)

    def add_point(self, x: np.ndarray, mask: int) -> int:
        """Store a new geometric point and return its id."""
        if self.npts == len(self.pos):
            self.pos = np.concatenate([self.pos, np.empty_like(self.pos)])
        pid = self.npts
        self.pos[pid] = x
        self.npts += 1
        self.mask.append(mask)
        self.pt_nodes.append([])
        self.index.add(pid, x)
        self.entered |= mask
        return pid

    def add_node(self, pid: int, q: int, parent: int, cost: float) -> int:
        """Create product node ``(point pid, q)`` under ``parent`` (-1 for a root)."""
        nid = len(self.node_q)
        self.node_pt.append(pid)
        self.node_q.append(q)
        self.parent.append(parent)
        self.cost.append(cost)
        self.children.append([])
        if parent >= 0:
            self.children[parent].append(nid)
        self.pt_nodes[pid].append(nid)
        self.lookup[(pid, q)] = nid
        layer = self.layers.get(q)
        if layer is None:
            layer = self.layers[q] = PointIndex(self.dim)
        layer.add(pid, self.pos[pid])
        return nid

    def near_radius(self) -> float:
        """RRT* neighbourhood radius ``min(gamma (log n / n)^(1/d), eta)``."""
        n = max(self.npts, 2)
        return min(self.gamma * (math.log(n) / n) ** (1.0 / self.dim), self.eta)

    def edges_ok(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) validity of geometric edges a[i]-b[i]: collision free, <= 1 label change."""
        return edges_ok(self.world, self.oracle, self.clearance, a, b)

    def extend(self, target: np.ndarray, layer: int | None = None) -> list[int]:
        """One RRT* step toward ``target`` from the nearest point of the tree (or of automaton
        layer ``layer``); returns the ids of the product nodes created (possibly none)."""
        index = self.index if layer is None else self.layers[layer]
        pid_near, dist = index.nearest(target)
        if dist <= 1e-12:
            return []
        x_near = self.pos[pid_near]
        x_new = target if dist <= self.eta else x_near + (target - x_near) * (self.eta / dist)
        if self.world.in_collision(x_new[None, :], self.clearance)[0]:
            return []
        near = self.index.within(x_new, self.near_radius())
        if not np.any(near == pid_near):
            near = np.append(near, pid_near)
        a = self.pos[near]
        diff = a - x_new
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        keep = d > 1e-12
        if not keep.all():
            return []
        ok = self.edges_ok(a, np.broadcast_to(x_new, a.shape))
        near, d = near[ok], d[ok]
        if near.size == 0:
            return []
        mask_new = self.oracle.masks(x_new[None, :])[0]
        near_l, d_l = near.tolist(), d.tolist()
        cost, node_q, succ, pt_nodes = self.cost, self.node_q, self.successors, self.pt_nodes
        # Cheapest way to reach x_new from each automaton state among the neighbours.
        via: dict[int, tuple[float, int]] = {}
        for pid, dd in zip(near_l, d_l, strict=True):
            for nid in pt_nodes[pid]:
                c = cost[nid] + dd
                q = node_q[nid]
                old = via.get(q)
                if old is None or c < old[0]:
                    via[q] = (c, nid)
        best: dict[int, tuple[float, int]] = {}
        for q, (c, nid) in via.items():
            for q2 in succ(q, mask_new):
                old = best.get(q2)
                if old is None or c < old[0]:
                    best[q2] = (c, nid)
        if not best:
            return []
        pid_new = self.add_point(x_new, mask_new)
        new = [self.add_node(pid_new, q2, best[q2][1], best[q2][0]) for q2 in sorted(best)]
        masks = self.mask
        for nid_new in new:
            q2 = node_q[nid_new]
            base = cost[nid_new]
            for pid, dd in zip(near_l, d_l, strict=True):
                c = base + dd
                nodes = [m for m in pt_nodes[pid] if c < cost[m] - 1e-12]
                if nodes:
                    reach = succ(q2, masks[pid])
                    for m in nodes:
                        if node_q[m] in reach:
                            self.reparent(m, nid_new, c)
        return new

    def reparent(self, nid: int, parent: int, cost: float) -> None:
        """Move ``nid`` under ``parent`` with the lower cost; descendants follow."""
        old = self.parent[nid]
        if old >= 0:
            self.children[old].remove(nid)
        self.parent[nid] = parent
        self.children[parent].append(nid)
        delta = cost - self.cost[nid]
        stack = [nid]
        while stack:
            k = stack.pop()
            self.cost[k] += delta
            stack.extend(self.children[k])

    def branch(self, nid: int) -> tuple[np.ndarray, list[int]]:
        """Points and automaton states from the root to node ``nid``."""
        nodes = []
        while nid >= 0:
            nodes.append(nid)
            nid = self.parent[nid]
        nodes.reverse()
        pts = self.pos[[self.node_pt[k] for k in nodes]].copy()
        return pts, [self.node_q[k] for k in nodes]
