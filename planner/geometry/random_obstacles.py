"""Random box obstacles: the ``random_obstacles`` generator of a world.

Boxes of one size are placed uniformly inside the bounds, each at least ``clearance`` away from
every labelled region and every keep-clear point (the robot's start), so that a generated clutter
never swallows a goal or the robot. Candidates are drawn in fixed-size batches from one seeded
generator and accepted independently of one another, so the result is deterministic for a seed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planner.errors import WorldError
from planner.geometry.shapes import Ball, Box, Polygon

BATCH = 256
"""Candidates drawn per round; fixed so the boxes depend on the seed only."""
TRIES_PER_BOX = 500
"""Candidates tried per requested box before giving up."""


def _point_box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance from each point (n,d) to its box (n,d corners); 0 inside."""
    gap = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return np.asarray(np.linalg.norm(gap, axis=-1))


def _box_box_distance(
    lo: np.ndarray, hi: np.ndarray, other_lo: np.ndarray, other_hi: np.ndarray
) -> np.ndarray:
    gap = np.maximum(np.maximum(lo - other_hi, other_lo - hi), 0.0)
    return np.asarray(np.linalg.norm(gap, axis=-1))


def _point_segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points (n,2) to the segment a-b (both (2,))."""
    ab = b - a
    t = np.clip(((points - a) @ ab) / float(ab @ ab), 0.0, 1.0)
    return np.asarray(np.linalg.norm(points - (a + t[:, None] * ab), axis=1))


def _segment_hits_boxes(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether the segment a-b meets each closed box (Liang-Barsky clipping), shape (n,)."""
    t0 = np.zeros(len(lo))
    t1 = np.ones(len(lo))
    hit = np.ones(len(lo), dtype=bool)
    for axis in range(len(a)):
        delta = b[axis] - a[axis]
        if delta == 0.0:
            hit &= (a[axis] >= lo[:, axis]) & (a[axis] <= hi[:, axis])
            continue
        ta = (lo[:, axis] - a[axis]) / delta
        tb = (hi[:, axis] - a[axis]) / delta
        t0 = np.maximum(t0, np.minimum(ta, tb))
        t1 = np.minimum(t1, np.maximum(ta, tb))
    return np.asarray(hit & (t0 <= t1))


def _points_in_polygon(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon test for points (n,2)."""
    inside = np.zeros(len(points), dtype=bool)
    x, y = points[:, 0], points[:, 1]
    for (x1, y1), (x2, y2) in zip(vertices, np.roll(vertices, -1, axis=0), strict=True):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < x_cross)
    return inside


def _box_polygon_distance(lo: np.ndarray, hi: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Exact distance from each 2D box to a simple polygon; 0 when they overlap.

    Two disjoint polygons are closest at a vertex of one and an edge of the other, so outside the
    overlapping case the distance is a minimum over vertex-edge pairs.
    """
    n = len(lo)
    corners = np.stack(
        [lo, np.stack([hi[:, 0], lo[:, 1]], axis=1), hi, np.stack([lo[:, 0], hi[:, 1]], axis=1)],
        axis=1,
    )  # (n, 4, 2)
    overlap = _points_in_polygon(corners.reshape(-1, 2), vertices).reshape(n, 4).any(axis=1)
    best = np.full(n, np.inf)
    for a, b in zip(vertices, np.roll(vertices, -1, axis=0), strict=True):
        overlap |= _segment_hits_boxes(a, b, lo, hi)
        best = np.minimum(best, _point_box_distance(np.broadcast_to(a, lo.shape), lo, hi))
        to_edge = _point_segment_distance(corners.reshape(-1, 2), a, b).reshape(n, 4)
        best = np.minimum(best, to_edge.min(axis=1))
    return np.where(overlap, 0.0, best)


def boxes_distance_to(shape: Box | Ball | Polygon, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from each box (rows of ``lo``/``hi``) to ``shape``; 0 on overlap."""
    if isinstance(shape, Box):
        return _box_box_distance(lo, hi, np.asarray(shape.lo), np.asarray(shape.hi))
    if isinstance(shape, Ball):
        centre = np.broadcast_to(np.asarray(shape.center, dtype=float), lo.shape)
        return np.maximum(_point_box_distance(centre, lo, hi) - float(shape.radius), 0.0)
    if isinstance(shape, Polygon):
        return _box_polygon_distance(lo, hi, np.asarray(shape.vertices, dtype=float))
    raise TypeError(f"unsupported shape {type(shape).__name__}")


def generate_boxes(
    bounds: np.ndarray,
    count: int,
    size: np.ndarray,
    seed: int,
    clearance: float,
    keep_clear: Sequence[np.ndarray] = (),
    avoid: Sequence[Box | Ball | Polygon] = (),
) -> list[Box]:
    """Place ``count`` boxes of edge lengths ``size`` uniformly inside ``bounds`` (d,2).

    Every box lies inside the bounds and stays at least ``clearance`` away from each point of
    ``keep_clear`` and each shape of ``avoid``; boxes may overlap one another. Raises
    ``WorldError`` (field ``world.random_obstacles.count``) when ``count`` boxes cannot be placed
    within ``TRIES_PER_BOX * count`` candidates.
    """
    bounds = np.asarray(bounds, dtype=float)
    size = np.asarray(size, dtype=float)
    rng = np.random.default_rng(seed)
    low, high = bounds[:, 0], bounds[:, 1] - size
    points = [np.asarray(p, dtype=float)[: len(size)] for p in keep_clear]
    placed: list[Box] = []
    budget = max(TRIES_PER_BOX * count, BATCH)
    tried = 0
    while len(placed) < count and tried < budget:
        lo = low + rng.random((BATCH, len(size))) * (high - low)
        hi = lo + size
        ok = np.ones(BATCH, dtype=bool)
        for p in points:
            ok &= _point_box_distance(np.broadcast_to(p, lo.shape), lo, hi) >= clearance
        for shape in avoid:
            ok &= boxes_distance_to(shape, lo, hi) >= clearance
        for i in np.flatnonzero(ok)[: count - len(placed)]:
            placed.append(Box(lo[i].copy(), hi[i].copy()))
        tried += BATCH
    if len(placed) < count:
        raise WorldError(
            "world.random_obstacles.count",
            f"could place only {len(placed)} of {count} boxes of size "
            f"{[float(s) for s in size]} at least {clearance:g} away from the regions and the "
            f"start after {tried} tries; lower count, size or clearance",
        )
    return placed
