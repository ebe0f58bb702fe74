"""Shapes of a world: axis-aligned boxes, balls (2D or 3D) and simple polygons (2D).

Every query is vectorised over n points or n segments. A ``margin`` inflates a shape by the
Minkowski sum with a ball of that radius (the robot's clearance): an inflated box has rounded
corners, it is not a bigger box. Shapes are closed sets: a point on the boundary is inside and a
segment that touches a shape intersects it.

Segment tests are exact (closest distance between the segment and the shape, compared with the
margin) and conservative against rounding: a segment whose distance is within ``SEGMENT_TOL`` of
the margin is reported as intersecting, so a colliding segment is never reported free.
``distance`` is unsigned: 0 inside the shape, the Euclidean distance to it outside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.geometry.segment_grid import near_segment_pairs

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

SEGMENT_TOL = 1e-9
"""Absolute slack added to the margin in segment tests so rounding can only err toward collision."""


def as_points(points: Any, dim: int) -> FloatArray:
    """``points`` as a float (n, dim) array; a single point (dim,) becomes (1, dim)."""
    p = np.asarray(points, dtype=float)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != dim:
        raise ValueError(f"expected points of shape (n, {dim}), got {p.shape}")
    return p


def _frozen_vector(value: Any, name: str, dims: tuple[int, ...]) -> FloatArray:
    arr = np.array(value, dtype=float)
    if arr.ndim != 1 or arr.shape[0] not in dims:
        allowed = " or ".join(str(d) for d in dims)
        raise ValueError(f"{name} must be a vector of length {allowed}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def box_sqdist(p: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """Squared distance from points to axis-aligned boxes; broadcasts over leading axes."""
    gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    return np.asarray((gap * gap).sum(axis=-1))


def segment_box_sqdist(a: FloatArray, b: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """Exact squared distance between segments ``a``-``b`` and boxes ``[lo, hi]`` (broadcasting).

    Along the segment the squared distance to a box is a convex piecewise quadratic whose pieces
    change only where a coordinate crosses ``lo`` or ``hi``; it is minimised on every piece in
    closed form and the smallest value is returned.
    """
    a, b, lo, hi = np.broadcast_arrays(a, b, lo, hi)
    u = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        knots = np.concatenate([(lo - a) / u, (hi - a) / u], axis=-1)
    knots = np.where(np.isfinite(knots), np.clip(knots, 0.0, 1.0), 0.0)
    ends = np.zeros((*knots.shape[:-1], 1))
    t = np.sort(np.concatenate([ends, knots, ends + 1.0], axis=-1), axis=-1)
    t0, t1 = t[..., :-1], t[..., 1:]
    A, U = a[..., None, :], u[..., None, :]
    LO, HI = lo[..., None, :], hi[..., None, :]
    xm = A + (0.5 * (t0 + t1))[..., None] * U
    below, above = xm < LO, xm > HI
    target = np.where(below, LO, HI)
    w = np.where(below | above, U, 0.0)
    num = (w * (target - A)).sum(axis=-1)
    den = (w * w).sum(axis=-1)
    ts = np.divide(num, den, out=0.5 * (t0 + t1), where=den > 0.0)
    ts = np.clip(ts, t0, t1)
    return np.asarray(box_sqdist(A + ts[..., None] * U, LO, HI).min(axis=-1))


def segment_point_sqdist(a: FloatArray, b: FloatArray, p: FloatArray) -> FloatArray:
    """Squared distance between segments ``a``-``b`` and points ``p`` (broadcasting)."""
    u = b - a
    uu = (u * u).sum(axis=-1)
    w = p - a
    t = np.divide(
        (w * u).sum(axis=-1), uu, out=np.zeros(np.broadcast(uu, w[..., 0]).shape), where=uu > 0.0
    )
    t = np.clip(t, 0.0, 1.0)
    diff = w - t[..., None] * u
    return np.asarray((diff * diff).sum(axis=-1))


def _cross2(u: FloatArray, v: FloatArray) -> FloatArray:
    return np.asarray(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])


def segment_segment_sqdist_2d(
    a: FloatArray, b: FloatArray, p: FloatArray, q: FloatArray
) -> FloatArray:
    """Squared distance between 2D segments ``a``-``b`` and ``p``-``q`` (0 if they cross)."""
    u, v = b - a, q - p
    o1, o2 = _cross2(u, p - a), _cross2(u, q - a)
    o3, o4 = _cross2(v, a - p), _cross2(v, b - p)
    crossing = (o1 * o2 < 0.0) & (o3 * o4 < 0.0)
    ends = np.minimum(
        np.minimum(segment_point_sqdist(a, b, p), segment_point_sqdist(a, b, q)),
        np.minimum(segment_point_sqdist(p, q, a), segment_point_sqdist(p, q, b)),
    )
    return np.asarray(np.where(crossing, 0.0, ends))


def first_close_edges(p: FloatArray, q: FloatArray, tol: float) -> tuple[int, int] | None:
    """The first pair ``(i, j)``, ``i < j``, of non-adjacent edges ``p[k]-q[k]`` of a closed
    ring that lie within ``tol`` of each other, in lexicographic order (None: no such pair).

    Only the pairs a uniform grid finds near each other are measured
    (``planner.geometry.segment_grid``): the answer is the all-pairs one, without its
    quadratic time and memory.
    """
    m = len(p)
    best: tuple[int, int] | None = None
    for pairs in near_segment_pairs(p, q, 2.0 * tol):
        i, j = pairs[:, 0], pairs[:, 1]
        adjacent = (j == i + 1) | ((i == 0) & (j == m - 1))
        d2 = segment_segment_sqdist_2d(p[i], q[i], p[j], q[j])
        bad = np.flatnonzero((~adjacent) & (d2 <= tol * tol))
        if len(bad):
            k = bad[np.lexsort((j[bad], i[bad]))[0]]
            found = (int(i[k]), int(j[k]))
            best = found if best is None else min(best, found)
    return best


@dataclass(frozen=True, eq=False, init=False)
class Box:
    """Axis-aligned box ``[lo, hi]`` in 2D or 3D (closed); ValueError if malformed."""

    lo: FloatArray
    hi: FloatArray

    def __init__(self, lo: ArrayLike, hi: ArrayLike) -> None:
        lo = _frozen_vector(lo, "box min", (2, 3))
        hi = _frozen_vector(hi, "box max", (2, 3))
        if lo.shape != hi.shape:
            raise ValueError(f"box min and max differ in dimension ({lo.size} vs {hi.size})")
        if not np.all(lo < hi):
            raise ValueError(f"box min {lo.tolist()} must be below max {hi.tolist()} on every axis")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Box)
            and np.array_equal(self.lo, other.lo)
            and np.array_equal(self.hi, other.hi)
        )

    def __hash__(self) -> int:
        return hash(("box", self.lo.tobytes(), self.hi.tobytes()))

    @property
    def dim(self) -> int:
        return int(self.lo.size)

    @property
    def volume(self) -> float:
        """Area in 2D, volume in 3D."""
        return float(np.prod(self.hi - self.lo))

    def bounding_box(self) -> tuple[FloatArray, FloatArray]:
        return self.lo.copy(), self.hi.copy()

    def distance(self, points: Any) -> FloatArray:
        return np.sqrt(box_sqdist(as_points(points, self.dim), self.lo, self.hi))

    def contains(self, points: Any, margin: float = 0.0) -> BoolArray:
        return box_sqdist(as_points(points, self.dim), self.lo, self.hi) <= margin * margin

    def sample(self, rng: np.random.Generator, n: int) -> FloatArray:
        return rng.uniform(self.lo, self.hi, size=(n, self.dim))

    def segments_intersect(self, a: Any, b: Any, margin: float = 0.0) -> BoolArray:
        d2 = segment_box_sqdist(as_points(a, self.dim), as_points(b, self.dim), self.lo, self.hi)
        return np.sqrt(d2) <= margin + SEGMENT_TOL

    def boundary_params(self, a: Any, b: Any) -> FloatArray:
        """(n, 2d) segment parameters where a coordinate meets a face plane (NaN: none).

        A superset of the parameters where the segment enters or leaves the box.
        """
        a, b = as_points(a, self.dim), as_points(b, self.dim)
        u = b - a
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.concatenate([(self.lo - a) / u, (self.hi - a) / u], axis=1)
        return np.where(np.isfinite(t), t, np.nan)


@dataclass(frozen=True, eq=False, init=False)
class Ball:
    """Closed ball (a disc in 2D, a sphere in 3D); ValueError if malformed."""

    center: FloatArray
    radius: float

    def __init__(self, center: ArrayLike, radius: float) -> None:
        center = _frozen_vector(center, "ball center", (2, 3))
        try:
            radius = float(radius)
        except (TypeError, ValueError):
            raise ValueError(f"ball radius must be a number, got {radius!r}") from None
        if not (math.isfinite(radius) and radius > 0.0):
            raise ValueError(f"ball radius must be a finite number > 0, got {radius}")
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "radius", radius)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Ball)
            and np.array_equal(self.center, other.center)
            and self.radius == other.radius
        )

    def __hash__(self) -> int:
        return hash(("ball", self.center.tobytes(), self.radius))

    @property
    def dim(self) -> int:
        return int(self.center.size)

    @property
    def volume(self) -> float:
        """Area in 2D, volume in 3D."""
        if self.dim == 2:
            return math.pi * self.radius**2
        return 4.0 / 3.0 * math.pi * self.radius**3

    def bounding_box(self) -> tuple[FloatArray, FloatArray]:
        return self.center - self.radius, self.center + self.radius

    def distance(self, points: Any) -> FloatArray:
        p = as_points(points, self.dim)
        return np.maximum(np.linalg.norm(p - self.center, axis=1) - self.radius, 0.0)

    def contains(self, points: Any, margin: float = 0.0) -> BoolArray:
        diff = as_points(points, self.dim) - self.center
        return np.asarray((diff * diff).sum(axis=1) <= (self.radius + margin) ** 2)

    def sample(self, rng: np.random.Generator, n: int) -> FloatArray:
        direction = rng.normal(size=(n, self.dim))
        norms = np.linalg.norm(direction, axis=1, keepdims=True)
        direction /= np.where(norms > 0.0, norms, 1.0)
        scale = self.radius * rng.uniform(size=(n, 1)) ** (1.0 / self.dim)
        return np.asarray(self.center + scale * direction)

    def segments_intersect(self, a: Any, b: Any, margin: float = 0.0) -> BoolArray:
        d2 = segment_point_sqdist(as_points(a, self.dim), as_points(b, self.dim), self.center)
        return np.sqrt(d2) <= self.radius + margin + SEGMENT_TOL

    def boundary_params(self, a: Any, b: Any) -> FloatArray:
        """(n, 2) segment parameters where the line meets the sphere (NaN: it does not)."""
        a, b = as_points(a, self.dim), as_points(b, self.dim)
        u, w = b - a, a - self.center
        qa = (u * u).sum(axis=1)
        qb = 2.0 * (u * w).sum(axis=1)
        qc = (w * w).sum(axis=1) - self.radius**2
        disc = qb * qb - 4.0 * qa * qc
        ok = (qa > 0.0) & (disc >= 0.0)
        root = np.sqrt(np.where(ok, disc, 0.0))
        den = np.where(ok, 2.0 * qa, 1.0)
        t = np.stack([(-qb - root) / den, (-qb + root) / den], axis=1)
        return np.where(ok[:, None], t, np.nan)


@dataclass(frozen=True, eq=False, init=False)
class Polygon:
    """Simple polygon in 2D, vertices in order (either orientation); ValueError if malformed.

    A repeated first vertex at the end (an explicitly closed ring) is dropped.
    """

    vertices: FloatArray

    def __init__(self, vertices: ArrayLike) -> None:
        v = np.array(vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2:
            raise ValueError(f"polygon vertices must be [[x, y], ...] in 2D, got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError("polygon vertices must be finite")
        if len(v) > 1 and np.array_equal(v[0], v[-1]):
            v = v[:-1]
        if len(v) < 3:
            raise ValueError(f"a polygon needs at least 3 distinct vertices, got {len(v)}")
        v.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        self._check_simple()
        if self.volume <= 0.0:
            raise ValueError("polygon has zero area (its vertices are collinear)")

    def _check_simple(self) -> None:
        p, q = self._edges()
        m = len(p)
        scale = float(np.abs(self.vertices).max()) + 1.0
        e = q - p
        if np.any(np.linalg.norm(e, axis=1) <= 1e-12 * scale):
            raise ValueError("polygon has repeated consecutive vertices")
        e_next = np.roll(e, -1, axis=0)
        folds = (np.abs(_cross2(e, e_next)) <= 1e-12 * scale**2) & ((e * e_next).sum(axis=1) < 0)
        if np.any(folds):
            k = int(np.argmax(folds))
            raise ValueError(f"polygon is not simple: edge {(k + 1) % m} folds back on edge {k}")
        crossing = first_close_edges(p, q, 1e-12 * scale)
        if crossing is not None:
            i, j = crossing
            raise ValueError(f"polygon is not simple: edge {i} touches or crosses edge {j}")

    def _edges(self) -> tuple[FloatArray, FloatArray]:
        return self.vertices, np.roll(self.vertices, -1, axis=0)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Polygon) and np.array_equal(self.vertices, other.vertices)

    def __hash__(self) -> int:
        return hash(("polygon", self.vertices.tobytes()))

    @property
    def dim(self) -> int:
        return 2

    @property
    def volume(self) -> float:
        """Area (shoelace formula)."""
        p, q = self._edges()
        return 0.5 * abs(float(_cross2(p, q).sum()))

    def bounding_box(self) -> tuple[FloatArray, FloatArray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def _inside_even_odd(self, p: FloatArray) -> BoolArray:
        v0, v1 = self._edges()
        x, y = p[:, :1], p[:, 1:]
        straddles = (v0[:, 1] > y) != (v1[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = v0[:, 0] + (y - v0[:, 1]) * (v1[:, 0] - v0[:, 0]) / (v1[:, 1] - v0[:, 1])
        crossings = (straddles & (x < x_cross)).sum(axis=1)
        return np.asarray(crossings % 2 == 1)

    def _edge_sqdist(self, p: FloatArray) -> FloatArray:
        v0, v1 = self._edges()
        return np.asarray(segment_point_sqdist(v0, v1, p[:, None, :]).min(axis=1))

    def distance(self, points: Any) -> FloatArray:
        p = as_points(points, 2)
        return np.where(self._inside_even_odd(p), 0.0, np.sqrt(self._edge_sqdist(p)))

    def contains(self, points: Any, margin: float = 0.0) -> BoolArray:
        p = as_points(points, 2)
        return self._inside_even_odd(p) | (self._edge_sqdist(p) <= margin * margin)

    def sample(self, rng: np.random.Generator, n: int) -> FloatArray:
        """Uniform points inside, by rejection from the bounding box."""
        lo, hi = self.bounding_box()
        ratio = self.volume / float(np.prod(hi - lo))
        found: list[FloatArray] = []
        count = 0
        while count < n:
            batch = int(1.2 * (n - count) / ratio) + 16
            pts = rng.uniform(lo, hi, size=(batch, 2))
            pts = pts[self._inside_even_odd(pts)]
            found.append(pts)
            count += len(pts)
        return np.concatenate(found)[:n] if found else np.empty((0, 2))

    def segments_intersect(self, a: Any, b: Any, margin: float = 0.0) -> BoolArray:
        a, b = as_points(a, 2), as_points(b, 2)
        v0, v1 = self._edges()
        d2 = segment_segment_sqdist_2d(a[:, None], b[:, None], v0, v1).min(axis=1)
        return self._inside_even_odd(a) | (np.sqrt(d2) <= margin + SEGMENT_TOL)

    def boundary_params(self, a: Any, b: Any) -> FloatArray:
        """(n, edges) segment parameters where the segment's line meets an edge (NaN: none)."""
        a, b = as_points(a, 2), as_points(b, 2)
        v0, v1 = self._edges()
        u, e = (b - a)[:, None, :], v1 - v0
        w = v0 - a[:, None, :]
        den = _cross2(u, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = _cross2(w, e) / den
            s = _cross2(w, u) / den
        hit = (den != 0.0) & (s >= 0.0) & (s <= 1.0)
        return np.where(hit, t, np.nan)


Shape = Box | Ball | Polygon
