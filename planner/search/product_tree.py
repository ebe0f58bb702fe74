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
from a neighbour with its cheapest parent, then rewire the neighbours through the new nodes.
Rewiring also *lifts*: a neighbour point that has no node yet in a state the new node leads to
gets one, parented by the new node. Without it every automaton layer has to rediscover the free
space by its own samples (a narrow door had to be found again by each state of a patrol); with
it a new state spreads over the points the tree already holds, one neighbourhood per sample;
:meth:`ProductTree.flood` spreads it at once over all of them, through the roadmap of segments
the tree has checked (:mod:`planner.search.roadmap`), which also starts suffix trees
(:meth:`ProductTree.seed_from`).

Per iteration the work is a handful of numpy operations over (neighbours x automaton states):
node ids live in a points x states table, costs in an array, and the successor relation in
boolean matrices per distinct label (:class:`TransitionTable`). Nearest and radius queries go
through :class:`~planner.search.point_index.PointIndex` (KD-tree plus a short scanned tail).
"""

from __future__ import annotations

import math

import numpy as np

from planner.geometry.labels import LabelOracle
from planner.geometry.world import World
from planner.search.point_index import PointIndex
from planner.search.product_edges import Successors, TransitionTable, edges_ok
from planner.search.roadmap import Roadmap, product_shortest_paths

_EPS = 1e-12
_STEPS = np.array([1.0, 0.5, 0.25])
"""Fractions of the steering step tried, longest first."""


class ProductTree:
    """RRT* tree in the product space; see the module docstring for the transition relation.

    ``node_at[pid, q]`` is the node of state q at point pid (-1: none); ``cost`` is an array
    indexed by node. ``layer(q)`` indexes the points carrying a node in state q. ``lift``
    switches the lifting of new states onto neighbour points (on by default).
    """

    def __init__(
        self,
        world: World,
        oracle: LabelOracle,
        successors: Successors,
        num_states: int,
        clearance: float,
        eta: float,
        gamma: float,
        lift: bool = True,
    ) -> None:
        self.world = world
        self.oracle = oracle
        self.successors = successors
        self.table = TransitionTable(successors, num_states)
        self.num_states = num_states
        self.clearance = clearance
        self.eta = eta
        self.gamma = gamma
        self.lift = lift
        self.dim = world.dim
        self.pos = np.empty((256, self.dim))
        self.label_ids = np.empty(256, dtype=np.int64)
        self.node_at = np.full((256, num_states), -1, dtype=np.int64)
        self.npts = 0
        self.mask: list[int] = []
        self.node_pt: list[int] = []
        self.node_q: list[int] = []
        self.parent: list[int] = []
        self.cost = np.full(1024, math.inf)
        self.children: list[list[int]] = []
        self.index = PointIndex(self.dim)
        """All points, for neighbour queries (seeded points included)."""
        self.reached = PointIndex(self.dim)
        """The points that carry a node: the tree grows from these."""
        self.layers: dict[int, PointIndex] = {}
        self.roots: list[int] = []
        self.roadmap = Roadmap()
        """The segments checked valid so far (a warm start for suffix trees)."""
        self.entered = 0
        """Union of the label masks of the reached points: the regions the tree has been in."""

    @property
    def num_nodes(self) -> int:
        return len(self.node_q)

    def add_point(self, x: np.ndarray, mask: int) -> int:
        """Store a new geometric point and return its id."""
        if self.npts == len(self.pos):
            self.pos = np.concatenate([self.pos, np.empty_like(self.pos)])
            self.label_ids = np.concatenate([self.label_ids, np.empty_like(self.label_ids)])
            self.node_at = np.concatenate([self.node_at, np.full_like(self.node_at, -1)])
        pid = self.npts
        self.pos[pid] = x
        self.label_ids[pid] = self.table.label_id(mask)
        self.npts += 1
        self.mask.append(mask)
        self.index.add(pid, x)
        return pid

    def seed_points(self, points: np.ndarray, masks: list[int]) -> None:
        """Add points without nodes (those another tree explored): neighbours that new nodes
        lift their states onto, so the tree does not have to find the same passages again."""
        for x, mask in zip(points, masks, strict=True):
            self.add_point(x, mask)

    def seed_from(self, other: ProductTree, pid: int, q: int) -> list[int]:
        """Become the product shortest-path tree, rooted at ``(other's point pid, q)``, of the
        roadmap ``other`` has checked (:mod:`planner.search.roadmap`); the tree must be empty
        and share ``other``'s world, clearance and automaton. Returns the nodes created."""
        order = [pid] + [k for k in range(other.npts) if k != pid]
        self.seed_points(other.pos[order], [other.mask[k] for k in order])
        new_id = np.empty(other.npts, dtype=np.int64)
        new_id[order] = np.arange(other.npts)
        u, v, d = other.roadmap.edges()
        self.roadmap.record_all(new_id[u], new_id[v], d)
        return [self.add_node(0, q, -1, 0.0), *self.flood()]

    def flood(self) -> list[int]:
        """Create every product node the roadmap reaches from the roots and the tree lacks,
        each under its predecessor on a shortest product path; returns the nodes created.

        The product nodes at a point appear one neighbourhood per step otherwise: a state
        reached in one goal region would have to spread over the explored space sample by
        sample before the tree could head for the next region."""
        u, v, d = self.roadmap.edges()
        if u.size == 0:
            return []
        q_count = self.num_states
        roots = [self.node_pt[n] * q_count + self.node_q[n] for n in self.roots]
        cost, pred = product_shortest_paths(
            u, v, d, self.label_ids[: self.npts], self.table.reach, roots
        )
        points, states = np.nonzero(np.isfinite(cost) & (self.node_at[: self.npts] < 0))
        rank = np.lexsort((states, points, cost[points, states]))
        points, states = points[rank], states[rank]
        before = pred[points, states]
        return self._add_flooded(points, states, before // q_count, before % q_count)

    def _add_flooded(
        self, pids: np.ndarray, qs: np.ndarray, parent_pids: np.ndarray, parent_qs: np.ndarray
    ) -> list[int]:
        """``add_node`` for the nodes ``(pids[k], qs[k])`` in this order, each under the node
        ``(parent_pids[k], parent_qs[k])`` (which exists, or comes earlier) at its cost plus
        the segment between their points: the same tree, in bulk."""
        if len(pids) == 0:
            return []
        first = len(self.node_q)
        at_points, first_at = np.unique(pids, return_index=True)
        unseen = ~(self.node_at[at_points] >= 0).any(axis=1)
        self.node_at[pids, qs] = np.arange(first, first + len(pids))
        parents = self.node_at[parent_pids, parent_qs]
        assert (parents >= 0).all(), "Dijkstra's predecessor is cheaper, hence exists already"
        parent_list = parents.tolist()
        nids = self._append(pids.tolist(), qs.tolist(), parent_list)
        cost = self.cost
        # sqrt(d . d) as np.linalg.norm computes it, bit for bit, without its overhead per row
        lengths = [math.sqrt(d.dot(d)) for d in self.pos[pids] - self.pos[parent_pids]]
        for nid, parent, length in zip(nids, parent_list, lengths, strict=True):
            cost[nid] = float(cost[parent]) + length
        reached = pids[np.sort(first_at[unseen])]  # points new to the tree, in order
        self.reached.add_many(reached, self.pos[reached])
        for pid in reached.tolist():
            self.entered |= self.mask[pid]
        for q in np.unique(qs).tolist():
            at = pids[qs == q]
            self._layer(q).add_many(at, self.pos[at])
        return nids

    def _append(self, pids: list[int], qs: list[int], parents: list[int]) -> list[int]:
        """The ids, lists and child links of new nodes ``(pids[k], qs[k])`` under
        ``parents[k]`` (-1: none), in this order, with room for them in the cost array; their
        costs, table entries and indexes are the caller's."""
        first = len(self.node_q)
        nids = list(range(first, first + len(pids)))
        while len(self.cost) < first + len(pids):
            self.cost = np.concatenate([self.cost, np.full_like(self.cost, math.inf)])
        self.node_pt.extend(pids)
        self.node_q.extend(qs)
        self.parent.extend(parents)
        self.children.extend([] for _ in nids)
        for nid, parent in zip(nids, parents, strict=True):
            if parent >= 0:
                self.children[parent].append(nid)
        return nids

    def _layer(self, q: int) -> PointIndex:
        """The index of the points that carry a node in state ``q``."""
        layer = self.layers.get(q)
        if layer is None:
            layer = self.layers[q] = PointIndex(self.dim)
        return layer

    def add_node(self, pid: int, q: int, parent: int, cost: float) -> int:
        """Create product node ``(point pid, q)`` under ``parent`` (-1 for a root)."""
        (nid,) = self._append([pid], [q], [parent])
        self.cost[nid] = cost
        if not (self.node_at[pid] >= 0).any():
            self.reached.add(pid, self.pos[pid])
            self.entered |= self.mask[pid]
        self.node_at[pid, q] = nid
        if parent < 0:
            self.roots.append(nid)
        self._layer(q).add(pid, self.pos[pid])
        return nid

    def node(self, pid: int, q: int) -> int:
        """The node of state ``q`` at point ``pid``, -1 if there is none."""
        return int(self.node_at[pid, q])

    def near_radius(self) -> float:
        """RRT* neighbourhood radius ``min(gamma (log n / n)^(1/d), eta)``."""
        n = max(self.npts, 2)
        return min(self.gamma * (math.log(n) / n) ** (1.0 / self.dim), self.eta)

    def near_count(self) -> int:
        """Most neighbours considered, ``e (1 + 1/d) log n`` (k-nearest RRT*): biased sampling
        piles points into goal regions and around a suffix root, where the radius alone
        would hand every step hundreds of candidate edges."""
        n = max(self.npts, 2)
        return max(8, math.ceil(math.e * (1.0 + 1.0 / self.dim) * math.log(n)))

    def edges_ok(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) validity of geometric edges a[i]-b[i]: collision free, <= 1 label change."""
        return edges_ok(self.world, self.oracle, self.clearance, a, b)

    def extend(self, target: np.ndarray, layer: int | None = None) -> list[int]:
        """One RRT* step toward ``target`` from the nearest point of the tree (or of automaton
        layer ``layer``); returns the ids of the product nodes created (possibly none), those at
        the new point first, then those lifted onto its neighbours."""
        index = self.reached if layer is None else self.layers[layer]
        pid_near, dist = index.nearest(target)
        if dist <= _EPS:
            return []
        x_near = self.pos[pid_near]
        # Steer by eta, or by half or a quarter of the step when the full one ends in an
        # obstacle: in clutter most full steps toward a goal region do, and a shorter free step
        # still extends the tree toward it.
        step = min(self.eta, dist) * _STEPS / dist
        tries = x_near + step[:, None] * (target - x_near)
        free = np.flatnonzero(~self.world.in_collision(tries, self.clearance))
        if free.size == 0:
            return []
        x_new = target if free[0] == 0 and dist <= self.eta else tries[free[0]]
        near = self.index.within(x_new, self.near_radius(), self.near_count())
        if not np.any(near == pid_near):
            near = np.append(near, pid_near)
        a = self.pos[near]
        diff = a - x_new
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        if not (d > _EPS).all():
            return []
        ok = self.edges_ok(a, np.broadcast_to(x_new, a.shape))
        near, d = near[ok], d[ok]
        if near.size == 0:
            return []
        mask_new = self.oracle.masks(x_new[None, :])[0]
        after = self.table.after[self.table.label_id(mask_new)]
        states = np.arange(self.num_states)
        nodes = self.node_at[near]
        through = np.where(nodes >= 0, self.cost[nodes] + d[:, None], math.inf)
        # Cheapest neighbour node in each automaton state, then for each successor state the
        # cheapest of those that steps to it under L(x_new), the first on a tie. Through the
        # successor lists of the states present: a (present, Q) array would be large for the
        # automaton of a finite any-order task (2^goals states).
        row = through.argmin(axis=0)
        via = through[row, states]
        present = np.flatnonzero(np.isfinite(via))
        if present.size == 0:
            return []
        via_l = via.tolist()
        best_l = [math.inf] * self.num_states
        src_l = [0] * self.num_states
        for p in present.tolist():
            v = via_l[p]
            for q in after[p]:
                if v < best_l[q]:
                    best_l[q], src_l[q] = v, p
        best, src = np.asarray(best_l), np.asarray(src_l)
        reached = np.flatnonzero(np.isfinite(best))
        if reached.size == 0:
            return []
        pid_new = self.add_point(x_new, mask_new)
        self.roadmap.record(pid_new, near, d)
        parents = nodes[row[src[reached]], src[reached]]
        new = self._add_at_new_point(pid_new, reached, parents, best[reached])
        return new + self._rewire(new, near, d)

    def _add_at_new_point(
        self, pid: int, qs: np.ndarray, parents: np.ndarray, costs: np.ndarray
    ) -> list[int]:
        """``add_node(pid, qs[k], parents[k], costs[k])`` for every k, in this order, at a
        point that has no node yet: the same tree, in bulk."""
        q_list = qs.tolist()
        nids = self._append([pid] * len(q_list), q_list, parents.tolist())
        self.cost[nids[0] : nids[-1] + 1] = costs
        self.reached.add(pid, self.pos[pid])
        self.entered |= self.mask[pid]
        self.node_at[pid, qs] = nids
        x = self.pos[pid]
        for q in q_list:
            self._layer(q).add(pid, x)
        return nids

    def _rewire(self, new: list[int], near: np.ndarray, d: np.ndarray) -> list[int]:
        """Reparent neighbour nodes through the new nodes where cheaper, and lift the new
        nodes' successor states onto neighbour points that lack them; returns lifted nodes."""
        labels = self.label_ids[near]
        near_l = near.tolist()
        lifted: list[int] = []
        # The neighbours' nodes and costs, kept up to date below as nodes are lifted and
        # reparented. A reparented node's descendants get cheaper too and are not updated:
        # their stale (higher) costs only let through candidates that the exact test drops.
        nodes = self.node_at[near]
        current = np.where(nodes >= 0, self.cost[nodes], math.inf if self.lift else -math.inf)
        after = [self.table.after[lid] for lid in labels.tolist()]
        d_l = d.tolist()
        # In the order of a loop over the new nodes, then the neighbours, then the states.
        for nid_new in new:
            q2 = self.node_q[nid_new]
            base = float(self.cost[nid_new])  # as it is now: rewiring may have lowered it
            for i, successors in enumerate(after):
                for q in successors[q2]:
                    c = base + d_l[i]
                    if not c < current[i, q] - _EPS:
                        continue
                    m = int(nodes[i, q])
                    if m < 0:
                        nodes[i, q] = m = self.add_node(near_l[i], q, nid_new, c)
                        lifted.append(m)
                        current[i, q] = c
                    elif c < self.cost[m] - _EPS:
                        self.reparent(m, nid_new, c)
                        current[i, q] = c
        return lifted

    def reparent(self, nid: int, parent: int, cost: float) -> None:
        """Move ``nid`` under ``parent`` with the lower cost; descendants follow."""
        old = self.parent[nid]
        if old >= 0:
            self.children[old].remove(nid)
        self.parent[nid] = parent
        self.children[parent].append(nid)
        delta = cost - self.cost[nid]
        subtree, stack = [nid], [nid]
        children = self.children
        while stack:
            kids = children[stack.pop()]
            if kids:
                subtree.extend(kids)
                stack.extend(kids)
        if len(subtree) == 1:
            self.cost[nid] += delta
        else:
            self.cost[subtree] += delta

    def branch(self, nid: int) -> tuple[np.ndarray, list[int]]:
        """Points and automaton states from the root to node ``nid``."""
        nodes = []
        while nid >= 0:
            nodes.append(nid)
            nid = self.parent[nid]
        nodes.reverse()
        pts = self.pos[[self.node_pt[k] for k in nodes]].copy()
        return pts, [self.node_q[k] for k in nodes]
