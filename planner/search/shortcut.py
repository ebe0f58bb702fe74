"""Anytime post-processing of a TL-RRT* lasso that keeps it a valid product run.

Tree branches zig-zag and their automaton transitions happen at whatever sample first entered
a region. Three local moves shorten the lasso while every product edge stays valid (collision
free, at most one label change, the automaton state of each waypoint a successor of the
previous one under the waypoint's label):

* *shortcut*: join waypoint i directly to the farthest j > i + 1 that keeps the run valid and
  skips only waypoints in the states of i or j (the sequence of automaton states, hence the
  cut into sub-tasks, is preserved);
* *tighten*: move a waypoint toward the chord of its neighbours (this never lengthens the path:
  the length is convex in the waypoint) by the largest step in 1, 1/2, ..., 1/16 that keeps the
  run valid; the shared point ``x*`` of prefix and suffix moves toward the weighted geometric
  median of its three neighbours, weighted by the lasso cost;
* *subdivide*: split long segments so that tightening can wrap obstacle corners and pull the
  transition points to the region boundaries.

Rounds of subdivide, tighten and shortcut repeat until the cost stops improving. Everything is
deterministic (no sampling), so the result depends only on the input lasso.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from planner.geometry.labels import LabelOracle
from planner.geometry.polyline import path_length
from planner.geometry.world import World
from planner.search.product_edges import Successors, edges_ok


@dataclass(frozen=True)
class LassoRun:
    """A lasso with its automaton run: ``suffix[0]`` and ``suffix[-1]`` are ``prefix[-1]``
    (a one-point suffix stays there forever); ``weight`` is the prefix weight of the cost."""

    prefix: np.ndarray
    suffix: np.ndarray
    prefix_states: list[int]
    suffix_states: list[int]
    weight: float

    @property
    def cost(self) -> float:
        return self.weight * path_length(self.prefix) + (1.0 - self.weight) * path_length(
            self.suffix
        )


def _directions(dim: int) -> np.ndarray:
    """Unit vectors toward the 3^d - 1 neighbours of a grid cell (8 in 2D, 26 in 3D)."""
    grid = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * dim, indexing="ij")).reshape(dim, -1).T
    grid = grid[np.any(grid != 0.0, axis=1)]
    return np.asarray(grid / np.linalg.norm(grid, axis=1, keepdims=True))


def _two_states_end(q: list[int], i: int) -> int:
    """The last waypoint a shortcut from waypoint ``i`` may reach: the states it skips,
    ``q[i..j-1]``, must be at most two (those of its two ends), so none reaches past the first
    waypoint of a third state."""
    seen = {q[i]}
    for k in range(i + 1, len(q)):
        seen.add(q[k])
        if len(seen) == 3:
            return k
    return len(q) - 1


class Ops:
    """The local moves of polishing and their validity checks (see the module docstring)."""

    def __init__(
        self, world: World, oracle: LabelOracle, succ: Successors, clearance: float
    ) -> None:
        self.world, self.oracle, self.succ, self.clearance = world, oracle, succ, clearance

    def ok(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return edges_ok(self.world, self.oracle, self.clearance, a, b)

    def free(self, x: np.ndarray) -> np.ndarray:
        return ~np.asarray(self.world.in_collision(x, self.clearance), dtype=bool)

    # ---------------------------------------------------------------------------- shortcut
    def shortcut(
        self, x: np.ndarray, q: list[int], accept: Callable[[int, int], bool] | None = None
    ) -> tuple[np.ndarray, list[int]]:
        """Greedy farthest-reachable shortcutting of one polyline with its states; ``accept``
        may veto the shortcut from waypoint i to j."""
        last = len(x) - 1
        if last < 2:
            return x, q
        masks = self.oracle.masks(x)
        keep = [0]
        i = 0
        while i < last:
            js = np.arange(i + 2, _two_states_end(q, i) + 1)
            best = i + 1
            if js.size:
                geo = self.ok(np.broadcast_to(x[i], (js.size, x.shape[1])), x[js])
                allowed = {q[i]}
                for j, g in zip(js.tolist(), geo.tolist(), strict=True):
                    allowed.add(q[j - 1])
                    valid = g and allowed <= {q[i], q[j]} and q[j] in self.succ(q[i], masks[j])
                    if valid and (accept is None or accept(i, j)):
                        best = j
            keep.append(best)
            i = best
        return x[keep], [q[k] for k in keep]

    # ----------------------------------------------------------------------------- tighten
    def tighten(self, x: np.ndarray, q: list[int]) -> np.ndarray:
        """One pass moving interior waypoints (even, then odd ones) toward their chords."""
        x = x.copy()
        for parity in (1, 2):
            ks = np.arange(parity, len(x) - 1, 2)
            if ks.size == 0:
                continue
            a, b, p = x[ks - 1], x[ks + 1], x[ks]
            ab = b - a
            den = np.einsum("ij,ij->i", ab, ab)
            t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(den > 0, den, 1.0), 0, 1)
            goal = a + t[:, None] * ab
            todo = np.ones(ks.size, dtype=bool)
            for step in (1.0, 0.5, 0.25, 0.125, 0.0625):
                idx = np.flatnonzero(todo)
                if idx.size == 0:
                    break
                cand = p[idx] + step * (goal[idx] - p[idx])
                good = self.moves_ok(
                    a[idx], cand, b[idx], [q[k - 1] for k in ks[idx]], [q[k] for k in ks[idx]]
                )
                x[ks[idx[good]]] = cand[good]
                todo[idx[good]] = False
        return x

    def moves_ok(
        self, a: np.ndarray, c: np.ndarray, b: np.ndarray, q_prev: list[int], q_here: list[int]
    ) -> np.ndarray:
        """Whether waypoints moved to ``c`` (between ``a`` and ``b``) keep the run valid."""
        good = self.free(c)
        idx = np.flatnonzero(good)
        if idx.size:
            geo = self.ok(np.vstack([a[idx], c[idx]]), np.vstack([c[idx], b[idx]]))
            good[idx] = geo[: idx.size] & geo[idx.size :]
        idx = np.flatnonzero(good)
        if idx.size:
            masks = self.oracle.masks(c[idx])
            for k, m in zip(idx.tolist(), masks, strict=True):
                good[k] = q_here[k] in self.succ(q_prev[k], m)
        return good

    def compass(self, x: np.ndarray, q: list[int]) -> np.ndarray:
        """One pattern-search pass: try each interior waypoint at fixed directions and
        fractions of its shorter adjacent segment, keep the cheapest valid improvement. Unlike
        :meth:`tighten` this slides waypoints along region and obstacle boundaries."""
        x = x.copy()
        dirs = _directions(x.shape[1])
        fracs = np.array([0.5, 0.25, 0.125, 0.0625])
        steps = (fracs[:, None, None] * dirs[None]).reshape(-1, x.shape[1])
        for parity in (1, 2):
            ks = np.arange(parity, len(x) - 1, 2)
            if ks.size == 0:
                continue
            a, b, p = x[ks - 1], x[ks + 1], x[ks]
            scale = np.minimum(np.linalg.norm(p - a, axis=1), np.linalg.norm(p - b, axis=1))
            cand = p[:, None, :] + scale[:, None, None] * steps[None]
            here = np.linalg.norm(p - a, axis=1) + np.linalg.norm(p - b, axis=1)
            cost = np.linalg.norm(cand - a[:, None], axis=2) + np.linalg.norm(
                cand - b[:, None], axis=2
            )
            better = cost < here[:, None] - 1e-12
            rows, cols = np.nonzero(better)
            if rows.size == 0:
                continue
            good = self.moves_ok(
                a[rows],
                cand[rows, cols],
                b[rows],
                [q[k - 1] for k in ks[rows]],
                [q[k] for k in ks[rows]],
            )
            score = np.full(better.shape, np.inf)
            score[rows[good], cols[good]] = cost[rows[good], cols[good]]
            pick = np.argmin(score, axis=1)
            moved = np.isfinite(score[np.arange(ks.size), pick])
            x[ks[moved]] = cand[np.flatnonzero(moved), pick[moved]]
        return x

    def move_star(self, run: LassoRun) -> LassoRun:
        """Move the shared point x* of prefix and suffix: toward the weighted geometric median
        of its neighbours, or by a pattern-search step, whichever valid move is cheapest."""
        p, s = run.prefix, run.suffix
        q_star = run.prefix_states[-1]
        x = p[-1]
        if len(p) < 2:
            return run
        if len(s) > 1:
            nbrs = np.array([p[-2], s[1], s[-2]])
            wts = np.array([run.weight, 1 - run.weight, 1 - run.weight])
        else:
            nbrs, wts = p[-2:-1], np.array([1.0])
        goal = x.copy()
        for _ in range(20):
            d = np.maximum(np.linalg.norm(nbrs - goal, axis=1), 1e-12)
            goal = (wts[:, None] * nbrs / d[:, None]).sum(axis=0) / (wts / d).sum()
        toward = x + np.array([1.0, 0.5, 0.25, 0.125, 0.0625])[:, None] * (goal - x)
        scale = float(np.linalg.norm(nbrs - x, axis=1).min())
        fracs = np.array([0.5, 0.25, 0.125, 0.0625])
        dirs = _directions(len(x))
        compass = x + scale * (fracs[:, None, None] * dirs[None]).reshape(-1, len(x))
        cand = np.vstack([toward, compass])
        cost = (wts * np.linalg.norm(cand[:, None, :] - nbrs[None], axis=2)).sum(axis=1)
        here = float((wts * np.linalg.norm(nbrs - x, axis=1)).sum())
        order = [int(i) for i in np.argsort(cost) if cost[i] < here - 1e-12]
        if not order:
            return run
        c = cand[order]
        good = self.free(c)
        idx = np.flatnonzero(good)
        if idx.size:
            k = len(nbrs)
            geo = self.ok(np.repeat(c[idx], k, axis=0), np.tile(nbrs, (idx.size, 1)))
            good[idx] = geo.reshape(idx.size, k).all(axis=1)
        for i in np.flatnonzero(good).tolist():
            m = self.oracle.masks(c[i][None, :])[0]
            if q_star not in self.succ(run.prefix_states[-2], m):
                continue
            loop_from = run.suffix_states[-2] if len(s) > 1 else q_star
            if q_star not in self.succ(loop_from, m):
                continue
            pre = p.copy()
            pre[-1] = c[i]
            suf = s.copy()
            suf[0] = c[i]
            suf[-1] = c[i]
            return replace(run, prefix=pre, suffix=suf)
        return run

    # --------------------------------------------------------------------------- subdivide
    def subdivide(self, x: np.ndarray, q: list[int], step: float) -> tuple[np.ndarray, list[int]]:
        """Split segments longer than ``step``; the new waypoints take the state of the
        segment's start until the label switches, then that of its end, when that is a valid
        run (otherwise the segment is left whole)."""
        out_x, out_q = [x[0]], [q[0]]
        for i in range(1, len(x)):
            a, b = x[i - 1], x[i]
            pieces = int(np.ceil(np.linalg.norm(b - a) / step))
            if pieces > 1:
                mids = a + (b - a) * (np.arange(1, pieces)[:, None] / pieces)
                states = self._split_states(
                    q[i - 1], q[i], self.oracle.masks(mids), self.oracle.masks(b[None, :])[0]
                )
                if states is not None:
                    out_x.extend(mids)
                    out_q.extend(states)
            out_x.append(b)
            out_q.append(q[i])
        return np.array(out_x), out_q

    def _split_states(self, qa: int, qb: int, masks: list[int], mask_b: int) -> list[int] | None:
        k = len(masks)
        for switch in range(k, -1, -1):
            states = [qa] * switch + [qb] * (k - switch)
            prev, fine = qa, True
            for st, m in zip([*states, qb], [*masks, mask_b], strict=True):
                if st not in self.succ(prev, m):
                    fine = False
                    break
                prev = st
            if fine:
                return states
        return None

    # ------------------------------------------------------------------------------ checks
    def valid(self, run: LassoRun) -> bool:
        """Exact re-check with the world's own functions (labels at waypoints, collisions)."""
        for x, q, first in (
            (run.prefix, run.prefix_states, True),
            (run.suffix, run.suffix_states, False),
        ):
            if len(x) > 1 and not np.all(self.world.segments_free(x[:-1], x[1:], self.clearance)):
                return False
            if len(x) > 1 and not np.all(self.oracle.changes(x[:-1], x[1:]) <= 1):
                return False
            cols = [self.world.region_names.index(n) for n in self.oracle.names]
            exact = self.world.label_matrix(x)[:, cols]
            if not np.array_equal(exact, self.oracle.membership(x)):
                return False
            masks = self.oracle.masks(x)
            start = 0 if first else 1
            for k in range(max(start, 1), len(x)):
                if q[k] not in self.succ(q[k - 1], masks[k]):
                    return False
        if len(run.suffix) == 1:
            m = self.oracle.masks(run.suffix)[0]
            return run.prefix_states[-1] in self.succ(run.prefix_states[-1], m)
        return True


def polish(
    run: LassoRun,
    world: World,
    oracle: LabelOracle,
    succ: Successors,
    clearance: float,
    eta: float,
    max_rounds: int = 12,
) -> LassoRun:
    """Shorten ``run`` by rounds of subdivide / tighten / shortcut (see the module docstring);
    returns ``run`` itself if nothing valid and cheaper is found."""
    ops = Ops(world, oracle, succ, clearance)
    best = _shortcut_run(ops, run)
    step = eta / 2.0
    for _ in range(max_rounds):
        cur = best
        p, pq = ops.subdivide(cur.prefix, cur.prefix_states, step)
        s, sq = ops.subdivide(cur.suffix, cur.suffix_states, step)
        cur = replace(cur, prefix=p, suffix=s, prefix_states=pq, suffix_states=sq)
        for _ in range(4):
            cur = replace(
                cur,
                prefix=ops.tighten(cur.prefix, cur.prefix_states),
                suffix=ops.tighten(cur.suffix, cur.suffix_states),
            )
            cur = ops.move_star(cur)
        for _ in range(3):
            cur = replace(
                cur,
                prefix=ops.compass(cur.prefix, cur.prefix_states),
                suffix=ops.compass(cur.suffix, cur.suffix_states),
            )
            cur = ops.move_star(cur)
        cur = _shortcut_run(ops, cur)
        if cur.cost >= best.cost * (1.0 - 1e-3):
            if cur.cost < best.cost:
                best = cur
            break
        best = cur
    if best is not run and not ops.valid(best):
        return run
    return best


def _shortcut_run(ops: Ops, run: LassoRun) -> LassoRun:
    p, pq = ops.shortcut(run.prefix, run.prefix_states)
    s, sq = ops.shortcut(run.suffix, run.suffix_states)
    if len(s) == 2 and np.array_equal(s[0], s[1]):
        s, sq = s[:1], sq[:1]
    return replace(run, prefix=p, suffix=s, prefix_states=pq, suffix_states=sq)
