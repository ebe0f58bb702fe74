"""A workspace: bounds, obstacles and labelled regions, with vectorised geometric queries.

The label function ``L(x)`` of the method is :meth:`World.labels`: the names of the regions
containing ``x`` (``World.labeler``, :mod:`planner.geometry.labels`) plus the reserved label
``"obstacle"`` inside any obstacle. Collision checks take
a ``clearance`` (the robot's radius): obstacles are inflated by it and the bounds shrunk by it.
Boxes and balls are stacked into arrays so a query over n points or segments is a handful of
numpy operations over (n x obstacles); only polygons are visited one by one.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from planner.errors import WorldError
from planner.geometry.labels import LabelOracle
from planner.geometry.shapes import (
    SEGMENT_TOL,
    Ball,
    BoolArray,
    Box,
    FloatArray,
    Polygon,
    Shape,
    as_points,
    box_sqdist,
    segment_box_sqdist,
    segment_point_sqdist,
)

IntArray = NDArray[np.int_]
_LABEL = re.compile(r"[a-z_][a-z0-9_]*\Z")
_CHUNK = 1024  # points or segments per vectorised pass: keeps temporaries in cache


class _ShapeSet:
    """Shapes stacked by kind: (k, d) arrays of box corners and ball centres, a polygon list."""

    def __init__(self, shapes: Sequence[Shape], dim: int) -> None:
        self.shapes = tuple(shapes)
        self.size = len(shapes)
        boxes = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Box)]
        balls = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Ball)]
        self.box_idx = np.array([i for i, _ in boxes], dtype=int)
        self.ball_idx = np.array([i for i, _ in balls], dtype=int)
        self.box_lo = np.array([s.lo for _, s in boxes], dtype=float).reshape(-1, dim)
        self.box_hi = np.array([s.hi for _, s in boxes], dtype=float).reshape(-1, dim)
        self.ball_c = np.array([s.center for _, s in balls], dtype=float).reshape(-1, dim)
        self.ball_r = np.array([s.radius for _, s in balls], dtype=float)
        self.balls = [s for _, s in balls]
        self.polygons = [(i, s) for i, s in enumerate(shapes) if isinstance(s, Polygon)]

    def _box_sqdist(self, p: FloatArray) -> FloatArray:
        """(n, boxes) squared distances, one axis at a time to keep temporaries (n, boxes)."""
        total = np.zeros((len(p), len(self.box_lo)))
        for j in range(p.shape[1]):
            x = p[:, j, None]
            gap = np.maximum(np.maximum(self.box_lo[:, j] - x, x - self.box_hi[:, j]), 0.0)
            total += gap * gap
        return total

    def _ball_sqdist(self, p: FloatArray) -> FloatArray:
        """(n, balls) squared distances to the ball centres."""
        total = np.zeros((len(p), len(self.ball_c)))
        for j in range(p.shape[1]):
            diff = p[:, j, None] - self.ball_c[:, j]
            total += diff * diff
        return total

    def contains(self, p: FloatArray, margin: float) -> BoolArray:
        """(n, k) membership of points in every shape inflated by ``margin``."""
        out = np.zeros((len(p), self.size), dtype=bool)
        if self.box_idx.size:
            out[:, self.box_idx] = self._box_sqdist(p) <= margin * margin
        if self.ball_idx.size:
            out[:, self.ball_idx] = self._ball_sqdist(p) <= (self.ball_r + margin) ** 2
        for i, poly in self.polygons:
            out[:, i] = poly.contains(p, margin)
        return out

    def nearest(self, p: FloatArray) -> FloatArray:
        """(n,) distance of each point to the nearest shape (0 inside one, inf: no shapes)."""
        out = np.full(len(p), np.inf)
        for i in range(0, len(p), _CHUNK):
            chunk = p[i : i + _CHUNK]
            near = out[i : i + _CHUNK]
            if self.box_idx.size:
                np.minimum(near, np.sqrt(self._box_sqdist(chunk).min(axis=1)), out=near)
            if self.ball_idx.size:
                gaps = np.sqrt(self._ball_sqdist(chunk)) - self.ball_r
                np.minimum(near, np.maximum(gaps.min(axis=1), 0.0), out=near)
            for _, poly in self.polygons:
                np.minimum(near, poly.distance(chunk), out=near)
        return out

    def any_contains(self, p: FloatArray, margin: float) -> BoolArray:
        """(n,) whether each point lies in some shape inflated by ``margin`` (chunked)."""
        if len(p) > _CHUNK:
            return np.concatenate(
                [self.any_contains(p[i : i + _CHUNK], margin) for i in range(0, len(p), _CHUNK)]
            )
        hit = np.zeros(len(p), dtype=bool)
        if self.box_idx.size:
            hit |= np.any(self._box_sqdist(p) <= margin * margin, axis=1)
        if self.ball_idx.size:
            hit |= np.any(self._ball_sqdist(p) <= (self.ball_r + margin) ** 2, axis=1)
        for _, poly in self.polygons:
            hit |= poly.contains(p, margin)
        return hit

    def any_segment_hits(self, a: FloatArray, b: FloatArray, margin: float) -> BoolArray:
        """(n,) whether each segment comes within ``margin`` of some shape (exact, conservative).

        Shapes whose inflated bounding box misses the bounding box of all the segments, then of
        each segment, are skipped before the exact distance test.
        """
        if len(a) > _CHUNK:
            return np.concatenate(
                [
                    self.any_segment_hits(a[i : i + _CHUNK], b[i : i + _CHUNK], margin)
                    for i in range(0, len(a), _CHUNK)
                ]
            )
        hit = np.zeros(len(a), dtype=bool)
        smin, smax = np.minimum(a, b), np.maximum(a, b)
        reach = margin + SEGMENT_TOL
        all_lo, all_hi = smin.min(axis=0) - reach, smax.max(axis=0) + reach
        if self.box_idx.size:
            cand = np.flatnonzero(np.all((self.box_lo <= all_hi) & (self.box_hi >= all_lo), axis=1))
            if cand.size:
                lo, hi = self.box_lo[cand] - reach, self.box_hi[cand] + reach
                near = np.ones((len(a), len(cand)), dtype=bool)
                for j in range(a.shape[1]):
                    near &= (smin[:, j, None] <= hi[:, j]) & (smax[:, j, None] >= lo[:, j])
                seg, box = np.nonzero(near)
                if seg.size:
                    box = cand[box]
                    d2 = segment_box_sqdist(a[seg], b[seg], self.box_lo[box], self.box_hi[box])
                    hit[seg[np.sqrt(d2) <= reach]] = True
        if self.ball_idx.size:
            r = self.ball_r[:, None]
            cand = np.flatnonzero(
                np.all((self.ball_c - r <= all_hi) & (self.ball_c + r >= all_lo), axis=1)
            )
            if cand.size:
                d2 = segment_point_sqdist(a[:, None, :], b[:, None, :], self.ball_c[cand])
                hit |= np.any(np.sqrt(d2) <= self.ball_r[cand] + reach, axis=1)
        for _, poly in self.polygons:
            p_lo, p_hi = poly.bounding_box()
            if np.all(p_lo <= all_hi) and np.all(p_hi >= all_lo):
                hit |= poly.segments_intersect(a, b, margin)
        return hit

    def boundary_params(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """(n, K) parameters along the segments where some shape boundary may be crossed."""
        parts: list[FloatArray] = [np.full((len(a), 0), np.nan)]
        if self.box_idx.size:
            u = (b - a)[:, None, :]
            with np.errstate(divide="ignore", invalid="ignore"):
                t_lo = (self.box_lo - a[:, None, :]) / u
                t_hi = (self.box_hi - a[:, None, :]) / u
            parts += [t_lo.reshape(len(a), -1), t_hi.reshape(len(a), -1)]
        parts += [ball.boundary_params(a, b) for ball in self.balls]
        parts += [poly.boundary_params(a, b) for _, poly in self.polygons]
        t = np.concatenate(parts, axis=1)
        return np.where(np.isfinite(t) & (t > 0.0) & (t < 1.0), t, 1.0)


class World:
    """Workspace bounds (d, 2), obstacles and named regions, in 2D or 3D."""

    OBSTACLE: ClassVar[str] = "obstacle"

    def __init__(
        self, bounds: Any, obstacles: Sequence[Shape], regions: Mapping[str, Shape]
    ) -> None:
        b = np.array(bounds, dtype=float)
        if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] not in (2, 3):
            raise WorldError("bounds", f"must be 2 or 3 intervals [lo, hi], got shape {b.shape}")
        if not np.all(np.isfinite(b)) or not np.all(b[:, 0] < b[:, 1]):
            raise WorldError("bounds", "every interval must be finite with lo < hi")
        b.setflags(write=False)
        self.bounds = b
        self.dim = int(b.shape[0])
        for i, shape in enumerate(obstacles):
            self._check_shape(f"obstacles[{i}]", shape)
        for name, shape in regions.items():
            if name == self.OBSTACLE or not _LABEL.match(name):
                raise WorldError(
                    f"regions.{name}",
                    "region names must match [a-z_][a-z0-9_]* and "
                    f"may not be the reserved label '{self.OBSTACLE}'",
                )
            self._check_shape(f"regions.{name}", shape)
        self.obstacles: tuple[Shape, ...] = tuple(obstacles)
        self.regions: dict[str, Shape] = dict(regions)
        self.region_names: tuple[str, ...] = tuple(self.regions)
        self._obs = _ShapeSet(self.obstacles, self.dim)
        self._reg = _ShapeSet([self.regions[n] for n in self.region_names], self.dim)
        self.labeler = LabelOracle(self, self.region_names)
        """``L(x)`` over every region (no obstacle label): one point, bitmasks, segments."""
        self._realisable_cache: dict[tuple[frozenset[str], frozenset[str], float], bool] = {}

    def _check_shape(self, field: str, shape: Shape) -> None:
        if not isinstance(shape, Box | Ball | Polygon):
            raise WorldError(field, f"expected a Box, Ball or Polygon, got {type(shape).__name__}")
        if shape.dim != self.dim:
            raise WorldError(field, f"is {shape.dim}D but the world is {self.dim}D")
        lo, hi = shape.bounding_box()
        if np.any(hi < self.bounds[:, 0]) or np.any(lo > self.bounds[:, 1]):
            raise WorldError(field, "lies entirely outside the world bounds")

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.bounds[:, 1] - self.bounds[:, 0]))

    @property
    def volume(self) -> float:
        """Measure of the whole workspace (area in 2D)."""
        return float(np.prod(self.bounds[:, 1] - self.bounds[:, 0]))

    def _inner_bounds(self, clearance: float) -> tuple[FloatArray, FloatArray]:
        return self.bounds[:, 0] + clearance, self.bounds[:, 1] - clearance

    def labels(self, x: Any) -> frozenset[str]:
        """``L(x)``: the regions containing ``x``, plus ``"obstacle"`` inside any obstacle."""
        p = as_points(x, self.dim)[:1]
        names = self.labeler.point_labels(p[0].tolist())
        if self._obs.any_contains(p, 0.0)[0]:
            return names | {self.OBSTACLE}
        return names

    def label_matrix(self, points: Any, margin: float = 0.0) -> BoolArray:
        """(n, len(region_names)) membership of each point in each region (no obstacle column),
        each region grown by ``margin``."""
        return self._reg.contains(as_points(points, self.dim), margin)

    def in_collision(self, points: Any, clearance: float = 0.0) -> BoolArray:
        """(n,) points within ``clearance`` of an obstacle or of the bounds (or outside them)."""
        p = as_points(points, self.dim)
        lo, hi = self._inner_bounds(clearance)
        out = np.any((p < lo) | (p > hi), axis=1)
        return np.asarray(out | self._obs.any_contains(p, clearance))

    def obstacle_distance(self, points: Any) -> FloatArray:
        """(n,) distance of each point to the nearest obstacle or bound (0 inside or outside):
        the largest clearance at which ``in_collision`` is false."""
        p = as_points(points, self.dim)
        to_bounds = np.minimum(p - self.bounds[:, 0], self.bounds[:, 1] - p).min(axis=1)
        return np.asarray(np.minimum(np.maximum(to_bounds, 0.0), self._obs.nearest(p)))

    def segments_free(self, a: Any, b: Any, clearance: float = 0.0) -> BoolArray:
        """(n,) whether each segment keeps ``clearance`` from every obstacle and from the bounds.

        Exact: the distance from the segment to each obstacle is compared with the clearance
        (up to a 1e-9 slack toward collision); the shrunk bounds are a box, so checking the two
        endpoints against them is enough.
        """
        a, b = as_points(a, self.dim), as_points(b, self.dim)
        lo, hi = self._inner_bounds(clearance)
        inside = np.all((np.minimum(a, b) >= lo) & (np.maximum(a, b) <= hi), axis=1)
        return np.asarray(inside & ~self._obs.any_segment_hits(a, b, clearance))

    def segment_free(self, a: Any, b: Any, clearance: float = 0.0) -> bool:
        return bool(self.segments_free(a, b, clearance)[0])

    def sample_free(self, rng: np.random.Generator, n: int, clearance: float = 0.0) -> FloatArray:
        """n uniform collision-free points; WorldError if free space looks empty."""
        lo, hi = self._inner_bounds(clearance)
        if np.any(lo > hi):
            raise WorldError("bounds", f"no room for a robot of clearance {clearance}")
        found: list[FloatArray] = []
        count, drawn = 0, 0
        while count < n:
            if drawn > 1000 * n + 100_000:
                raise WorldError(
                    "obstacles",
                    "no collision-free point found: the obstacles "
                    f"(inflated by {clearance}) seem to cover the workspace",
                )
            batch = 2 * (n - count) + 64
            pts = rng.uniform(lo, hi, size=(batch, self.dim))
            pts = pts[~self._obs.any_contains(pts, clearance)]
            found.append(pts)
            count += len(pts)
            drawn += batch
        return np.concatenate(found)[:n]

    def region(self, label: str) -> Shape:
        """The shape of region ``label``; WorldError naming the known regions if absent."""
        try:
            return self.regions[label]
        except KeyError:
            known = ", ".join(self.region_names) or "none"
            raise WorldError(f"regions.{label}", f"no such region (known: {known})") from None

    def sample_region(
        self, label: str, rng: np.random.Generator, n: int, clearance: float = 0.0
    ) -> FloatArray:
        """Up to n uniform points of region ``label`` that are collision free (m <= n rows)."""
        pts = self.region(label).sample(rng, n)
        return pts[~self.in_collision(pts, clearance)]

    def segments_label_changes(self, a: Any, b: Any) -> IntArray:
        """(n,) how many times ``L`` changes along each segment (as an integer array).

        Exact up to rounding: the segment is cut at every parameter where it may cross a region
        or obstacle boundary, and labels are compared at the cuts and between them, so a
        segment that only grazes a region still counts two changes.
        """
        a, b = as_points(a, self.dim), as_points(b, self.dim)
        knots = np.concatenate(
            [self._reg.boundary_params(a, b), self._obs.boundary_params(a, b)], axis=1
        )
        n = len(a)
        cuts = np.sort(np.concatenate([np.zeros((n, 1)), knots, np.ones((n, 1))], axis=1), axis=1)
        t = np.sort(np.concatenate([cuts, 0.5 * (cuts[:, 1:] + cuts[:, :-1])], axis=1), axis=1)
        pts = (a[:, None, :] + t[:, :, None] * (b - a)[:, None, :]).reshape(-1, self.dim)
        lab = np.concatenate(
            [self._reg.contains(pts, 0.0), self._obs.any_contains(pts, 0.0)[:, None]], axis=1
        )
        lab = lab.reshape(n, t.shape[1], -1)
        return np.asarray(np.any(lab[:, 1:] != lab[:, :-1], axis=2).sum(axis=1))

    def segment_label_changes(self, a: Any, b: Any) -> int:
        """How many times the label set changes along the segment ``a``-``b``."""
        return int(self.segments_label_changes(a, b)[0])

    def realisable(
        self, cube_pos: frozenset[str], cube_neg: frozenset[str], clearance: float = 0.0
    ) -> bool:
        """Whether some free point carries every label of ``cube_pos`` and none of ``cube_neg``.

        ``"obstacle"`` in ``cube_pos`` or an unknown positive label: False. Disjoint pairs of box
        and ball regions are detected exactly; otherwise a witness is searched by sampling
        (4096 points per round, fixed seed) inside the intersection of the positive regions'
        bounding boxes, so an overlap thinner than the sampling resolution counts as empty.
        """
        key = (frozenset(cube_pos), frozenset(cube_neg), float(clearance))
        if key not in self._realisable_cache:
            self._realisable_cache[key] = self._realisable(*key)
        return self._realisable_cache[key]

    def _realisable(self, pos: frozenset[str], neg: frozenset[str], clearance: float) -> bool:
        if self.OBSTACLE in pos or not pos <= set(self.region_names) or pos & neg:
            return False
        shapes = [self.regions[n] for n in sorted(pos)]
        for i, s in enumerate(shapes):
            if any(_disjoint(s, t) for t in shapes[i + 1 :]):
                return False
        lo, hi = self._inner_bounds(clearance)
        for s in shapes:
            s_lo, s_hi = s.bounding_box()
            lo, hi = np.maximum(lo, s_lo), np.minimum(hi, s_hi)
        if np.any(lo > hi):
            return False
        pos_cols = [self.region_names.index(n) for n in pos]
        neg_cols = [self.region_names.index(n) for n in neg if n in self.region_names]
        rng = np.random.default_rng(0)
        for _ in range(4):
            pts = rng.uniform(lo, hi, size=(4096, self.dim))
            lab = self.label_matrix(pts)
            ok = lab[:, pos_cols].all(axis=1) & ~lab[:, neg_cols].any(axis=1)
            ok &= ~self.in_collision(pts, clearance)
            if np.any(ok):
                return True
        return False


def _disjoint(s: Shape, t: Shape) -> bool:
    """Exact emptiness of the intersection of two boxes/balls (False when unsure: polygons)."""
    if isinstance(s, Box) and isinstance(t, Box):
        return bool(np.any(s.hi < t.lo) or np.any(t.hi < s.lo))
    if isinstance(s, Ball) and isinstance(t, Ball):
        return bool(np.linalg.norm(s.center - t.center) > s.radius + t.radius)
    if isinstance(s, Box) and isinstance(t, Ball):
        return bool(box_sqdist(t.center, s.lo, s.hi) > t.radius**2)
    if isinstance(s, Ball) and isinstance(t, Box):
        return _disjoint(t, s)
    return False
