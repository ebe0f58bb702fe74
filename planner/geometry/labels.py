"""The label function ``L(x)`` over regions: one point at a time, as bitmasks, along segments.

:meth:`LabelOracle.point_labels` is ``L(x)`` of one point without the obstacle label (the
world's :meth:`World.labels` adds that label; an env's robot inside an obstacle has crashed
already), with scalar region tests (:mod:`planner.geometry.region_test`) fast enough for every
env step.

TL-RRT* asks for the label of every new sample and for the number of label changes along every
candidate edge, thousands of times per second. :meth:`World.label_matrix` and
:meth:`World.segments_label_changes` answer them exactly, shape by shape; this oracle answers
the same questions for all regions at once with a few numpy operations (boxes, balls and
polygons are stacked by kind), restricted to the regions the task talks about: only the
formula's atoms can influence the automaton, so a label change of another region along an edge
is irrelevant to the run. It agrees with :meth:`World.label_matrix` away
from region boundaries (boundary points form a set of measure zero that random samples do not
hit), and the planner re-checks the final lasso with the world's exact functions.

A region of an unknown shape kind is delegated to the world's own (slower) functions.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from planner.geometry.region_test import RegionTest
from planner.geometry.shapes import Ball, Box, Polygon

if TYPE_CHECKING:
    from planner.geometry.world import World

_MAX_INT_BITS = 62


class LabelOracle:
    """Bitmask labels over ``names``: the world's regions that are atoms of the task.

    Bit ``i`` of a mask is set when the point lies in region ``names[i]``. ``label(mask)`` turns
    a mask back into the frozenset of region names used by the automaton.
    """

    def __init__(self, world: World, atoms: Iterable[str]) -> None:
        wanted = set(atoms)
        self.world = world
        self.names: tuple[str, ...] = tuple(n for n in world.region_names if n in wanted)
        self.dim = world.dim
        shapes = [world.regions[n] for n in self.names]
        boxes = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Box)]
        balls = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Ball)]
        polys = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Polygon)]
        self._box = [i for i, _ in boxes]
        self._ball = [i for i, _ in balls]
        self._poly = [i for i, _ in polys]
        known = set(self._box) | set(self._ball) | set(self._poly)
        self._other = [i for i in range(len(shapes)) if i not in known]
        d = self.dim
        self.box_lo = np.array([b.lo for _, b in boxes], dtype=np.float64).reshape(-1, d)
        self.box_hi = np.array([b.hi for _, b in boxes], dtype=np.float64).reshape(-1, d)
        self.ball_c = np.array([b.center for _, b in balls], dtype=np.float64).reshape(-1, d)
        self.ball_r2 = np.array([b.radius**2 for _, b in balls], dtype=np.float64)
        v0: list[np.ndarray] = []
        v1: list[np.ndarray] = []
        starts: list[int] = []
        for _, poly in polys:
            v = np.asarray(poly.vertices, dtype=np.float64)
            starts.append(sum(len(e) for e in v0))
            v0.append(v)
            v1.append(np.roll(v, -1, axis=0))
        self.e0 = np.concatenate(v0) if v0 else np.zeros((0, 2))
        self.e1 = np.concatenate(v1) if v1 else np.zeros((0, 2))
        self.edge_starts = np.array(starts, dtype=np.int64)
        with np.errstate(divide="ignore", invalid="ignore"):
            self.edge_slope = (self.e1[:, 0] - self.e0[:, 0]) / (self.e1[:, 1] - self.e0[:, 1])
        lows, highs = [], []
        for s in shapes:
            lo, hi = s.bounding_box()
            lows.append(lo)
            highs.append(hi)
        self.bb_lo = np.array(lows, dtype=np.float64).reshape(-1, d)
        self.bb_hi = np.array(highs, dtype=np.float64).reshape(-1, d)
        self.wide = len(self.names) > _MAX_INT_BITS
        self.weights = (
            np.ones(len(self.names), dtype=np.int64)
            if self.wide
            else (np.int64(1) << np.arange(len(self.names), dtype=np.int64))
        )
        self._labels: dict[int, frozenset[str]] = {}
        self._tests = [(1 << k, RegionTest(s)) for k, s in enumerate(shapes)]

    def label(self, mask: int) -> frozenset[str]:
        """The frozenset of region names of a mask (cached)."""
        got = self._labels.get(mask)
        if got is None:
            got = frozenset(n for i, n in enumerate(self.names) if (mask >> i) & 1)
            self._labels[mask] = got
        return got

    def point_labels(self, x: Sequence[float]) -> frozenset[str]:
        """``L(x)`` over ``names`` for one point ``x`` (equal labels are the same object)."""
        mask = 0
        for bit, test in self._tests:
            if test.contains(x):
                mask |= bit
        return self.label(mask)

    def membership(self, points: np.ndarray) -> np.ndarray:
        """(n, len(names)) membership of points in the task's regions."""
        p = np.asarray(points, dtype=float).reshape(-1, self.dim)
        out = np.zeros((len(p), len(self.names)), dtype=bool)
        if self._box:
            out[:, self._box] = np.all(
                (p[:, None, :] >= self.box_lo) & (p[:, None, :] <= self.box_hi), axis=2
            )
        if self._ball:
            diff = p[:, None, :] - self.ball_c
            out[:, self._ball] = np.einsum("nkd,nkd->nk", diff, diff) <= self.ball_r2
        if self._poly:
            x, y = p[:, :1], p[:, 1:2]
            straddle = (self.e0[:, 1] > y) != (self.e1[:, 1] > y)
            with np.errstate(invalid="ignore"):
                x_cross = self.e0[:, 0] + (y - self.e0[:, 1]) * self.edge_slope
            odd = straddle & (x < x_cross)
            counts = np.add.reduceat(odd.astype(np.int64), self.edge_starts, axis=1)
            out[:, self._poly] = (counts & 1).astype(bool)
        if self._other:
            cols = [self.world.region_names.index(self.names[i]) for i in self._other]
            out[:, self._other] = self.world.label_matrix(p)[:, cols]
        return out

    def masks(self, points: np.ndarray) -> list[int]:
        """Bitmask label of each point, as Python ints (hashable automaton-cache keys)."""
        member = self.membership(points)
        if not self.wide:
            return (member.astype(np.int64) @ self.weights).tolist()
        return [sum(1 << int(i) for i in np.flatnonzero(row)) for row in member]

    def changes(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) number of times the task label changes along each segment ``a[i]``-``b[i]``.

        Every proper crossing of a region boundary toggles that region's membership, so the
        label changes once per distinct crossing parameter: the crossings are computed in
        closed form (slabs for boxes, roots for balls, edge intersections for polygons) and
        counted without evaluating a single label. Tangencies and segments running along an
        edge (sets of measure zero) are ignored.
        """
        a = np.asarray(a, dtype=float).reshape(-1, self.dim)
        b = np.asarray(b, dtype=float).reshape(-1, self.dim)
        out = np.zeros(len(a), dtype=np.int64)
        if not self.names:
            return out
        smin, smax = np.minimum(a, b), np.maximum(a, b)
        near = np.all(
            (smin[:, None, :] <= self.bb_hi) & (smax[:, None, :] >= self.bb_lo), axis=2
        ).any(axis=1)
        rows = np.flatnonzero(near)
        if rows.size == 0:
            return out
        if self._other:
            out[rows] = self.world.segments_label_changes(a[rows], b[rows])
            return out
        t = np.sort(self._crossings(a[rows], b[rows]), axis=1)
        finite = np.isfinite(t)
        repeat = finite[:, 1:] & (np.diff(t, axis=1) <= 1e-12)
        out[rows] = finite.sum(axis=1) - repeat.sum(axis=1)
        return out

    def _crossings(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n, K) parameters in (0, 1) where segments cross a region boundary (NaN: none)."""
        u = b - a
        parts = [np.full((len(a), 0), np.nan)]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self._box:
                t_lo = (self.box_lo - a[:, None, :]) / u[:, None, :]
                t_hi = (self.box_hi - a[:, None, :]) / u[:, None, :]
                flat = u[:, None, :] == 0.0
                inside = (a[:, None, :] >= self.box_lo) & (a[:, None, :] <= self.box_hi)
                near_t = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t_lo, t_hi))
                far_t = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t_lo, t_hi))
                enter = near_t.max(axis=2)
                leave = far_t.min(axis=2)
                hit = enter < leave
                parts += [np.where(hit, enter, np.nan), np.where(hit, leave, np.nan)]
            if self._ball:
                w = a[:, None, :] - self.ball_c
                qa = (u * u).sum(axis=1)[:, None]
                qb = 2.0 * np.einsum("nd,nkd->nk", u, w)
                qc = np.einsum("nkd,nkd->nk", w, w) - self.ball_r2
                disc = qb * qb - 4.0 * qa * qc
                root = np.sqrt(np.where(disc > 0.0, disc, np.nan))
                parts += [(-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa)]
            if self._poly:
                e = self.e1 - self.e0
                w = self.e0 - a[:, None, :]
                uu = u[:, None, :]
                den = uu[..., 0] * e[:, 1] - uu[..., 1] * e[:, 0]
                tt = (w[..., 0] * e[:, 1] - w[..., 1] * e[:, 0]) / den
                ss = (w[..., 0] * uu[..., 1] - w[..., 1] * uu[..., 0]) / den
                parts.append(np.where((ss >= 0.0) & (ss <= 1.0), tt, np.nan))
        t = np.concatenate(parts, axis=1)
        return np.where((t > 0.0) & (t < 1.0), t, np.nan)
