"""Analytic ray casts from the robot's point to the nearest obstacle surface or world boundary.

The observation's optional lidar-like scan (``envs.observation``): ``RayCaster.cast_scaled``
gives each ray's distance divided by its range, clipped to ``[0, 1]``. Nearby obstacles are
gathered per grid cell once and cast against in a few vectorised numpy calls; ``cast_general``
is the plain reference path used on and outside the bounds. The fast path's cells are in
``envs.ray_cells``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from envs.ray_cells import FastCell2, FastCell3, gap
from envs.robots import RobotParams, top_speed
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World

if TYPE_CHECKING:
    from envs.options import EnvOptions

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]


RAY_SECONDS = 3.5
"""The default ray range in seconds at the robot's top speed: 3.5 m for the built-in robots
(1 m/s), which the world-scaled default (an eighth of the diagonal) gave in the 20 m worlds the
controllers and rewards were measured in."""


def default_ray_range(params: RobotParams) -> float:
    """How far the rays of a robot of ``params`` see unless ``ray_range`` is set:
    ``RAY_SECONDS`` of its top speed, and at least two of its tightest turning radii (room to
    swerve round what it sees)."""
    return max(RAY_SECONDS * top_speed(params), 2.0 * params.min_turning_radius())


def ray_reach(options: EnvOptions, params: RobotParams) -> float:
    """How far the rays see under ``options`` for a robot of ``params``: ``ray_range``, else
    ``default_ray_range``."""
    return options.ray_range if options.ray_range is not None else default_ray_range(params)


def ray_directions(dim: int, count: int) -> FloatArray:
    """``(count, dim)`` unit directions: evenly spaced angles from +x in 2D, a Fibonacci sphere
    in 3D."""
    k = np.arange(count, dtype=float)
    if dim == 2:
        angle = 2.0 * math.pi * k / count
        return np.stack([np.cos(angle), np.sin(angle)], axis=1)
    z = 1.0 - 2.0 * (k + 0.5) / count
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


class _Cell:
    """The obstacles a ray cast from one grid cell can reach, stacked by kind (general path)."""

    def __init__(
        self,
        corners: FloatArray,
        ball_c: FloatArray,
        ball_r2: FloatArray,
        edge_a: FloatArray,
        edge_e: FloatArray,
    ) -> None:
        self.corners = corners
        """``(2, 1 + boxes, d)``: lower and upper corners of the bounds, then of each box."""
        self.ball_c: FloatArray | None = ball_c if len(ball_c) else None
        self.ball_r2: FloatArray | None = ball_r2 if len(ball_c) else None
        self.edge_a: FloatArray | None = edge_a if len(edge_a) else None
        self.edge_e: FloatArray | None = edge_e if len(edge_a) else None


class RayCaster:
    """Exact distances along rays to boxes, balls, polygon edges and the world bounds.

    Only obstacles that come within ``max_range`` of the robot's grid cell (cell size
    ``max_range / 2``) are cast against; those sets are built lazily per cell and stacked into
    one matrix, so that a cast is a dozen numpy calls over rays x nearby obstacles: in 2D every
    box, polygon and bounds edge is a segment (ray/segment intersection), in 3D boxes and the
    outside of the bounds are slabs; balls solve the quadratic. A ray that starts inside an
    obstacle reads 0 for a box, the exit distance for a polygon and ignores a ball (the robot
    has crashed then anyway); points outside the open bounds or in (or on) a box take the
    general path (``cast_general``), which defines these cases.
    """

    def __init__(self, world: World, count: int, max_range: float) -> None:
        self.dim = world.dim
        self.count = count
        self.max_range = float(max_range)
        self.directions = ray_directions(self.dim, count)
        self._inv_dir = 1.0 / (self.directions + 1e-15)
        self._lo = np.asarray(world.bounds[:, 0], dtype=float)
        self._hi = np.asarray(world.bounds[:, 1], dtype=float)
        self._origin = self._lo.tolist()
        self._lo_t, self._hi_t = self._lo.tolist(), self._hi.tolist()
        self._cell_size = self.max_range / 2.0
        self._inv_size = 1.0 / self._cell_size
        obstacles = list(world.obstacles)
        boxes = [s for s in obstacles if isinstance(s, Box)]
        balls = [s for s in obstacles if isinstance(s, Ball)]
        polygons = [s for s in obstacles if isinstance(s, Polygon)] if self.dim == 2 else []
        d = self.dim
        self._box_lo = np.array([b.lo for b in boxes], dtype=float).reshape(-1, d)
        self._box_hi = np.array([b.hi for b in boxes], dtype=float).reshape(-1, d)
        self._ball_c = np.array([b.center for b in balls], dtype=float).reshape(-1, d)
        self._ball_r = np.array([b.radius for b in balls], dtype=float)
        a = [p.vertices for p in polygons]
        b = [np.roll(p.vertices, -1, axis=0) for p in polygons]
        self._edge_a = np.concatenate(a).reshape(-1, 2) if a else np.zeros((0, 2))
        self._edge_b = np.concatenate(b).reshape(-1, 2) if b else np.zeros((0, 2))
        self._cells: dict[tuple[int, ...], _Cell] = {}
        self._fast: dict[tuple[int, ...], FastCell2 | FastCell3] = {}

    def _key(self, x: Sequence[float]) -> tuple[int, ...]:
        size = self._cell_size
        return tuple([math.floor((v - o) / size) for v, o in zip(x, self._origin, strict=False)])

    def _cell(self, x: Sequence[float]) -> _Cell:
        key = self._key(x)
        found = self._cells.get(key)
        if found is None:
            size = self._cell_size
            lo = self._lo + np.asarray(key, dtype=float) * size - self.max_range
            hi = lo + size + 2.0 * self.max_range
            box = np.all((self._box_lo <= hi) & (self._box_hi >= lo), axis=1)
            r = self._ball_r[:, None]
            ball = np.all((self._ball_c - r <= hi) & (self._ball_c + r >= lo), axis=1)
            e_lo = np.minimum(self._edge_a, self._edge_b)
            e_hi = np.maximum(self._edge_a, self._edge_b)
            edge = np.all((e_lo <= hi[:2]) & (e_hi >= lo[:2]), axis=1)
            corners = np.stack(
                [
                    np.concatenate([self._lo[None, :], self._box_lo[box]]),
                    np.concatenate([self._hi[None, :], self._box_hi[box]]),
                ]
            )
            found = _Cell(
                corners,
                self._ball_c[ball],
                self._ball_r[ball] ** 2,
                self._edge_a[edge],
                (self._edge_b - self._edge_a)[edge],
            )
            self._cells[key] = found
        return found

    def cast(self, x: Sequence[float], rotation: tuple[float, float] | None = None) -> FloatArray:
        """``(count,)`` distances from ``x`` along every ray, capped at ``max_range``; in 2D
        ``rotation = (cos, sin)`` turns the rays by the robot's heading."""
        fast = self._scaled2(x, rotation) if self.dim == 2 else self._scaled3(x)
        if fast is None:
            return self.cast_general(x, rotation)
        return np.array(fast) * self.max_range

    def cast_scaled(
        self, x: Sequence[float], rotation: tuple[float, float] | None = None
    ) -> list[float]:
        """:meth:`cast` divided by ``max_range`` and clipped to ``[0, 1]``, as a list (what the
        observation holds)."""
        fast = self._scaled2(x, rotation) if self.dim == 2 else self._scaled3(x)
        if fast is None:
            ranges = self.cast_general(x, rotation) * (1.0 / self.max_range)
            return np.minimum(np.maximum(ranges, 0.0), 1.0).tolist()
        return fast

    def _fast_cell(self, key: tuple[int, ...]) -> FastCell2 | FastCell3:
        cell = FastCell2(self, key) if self.dim == 2 else FastCell3(self, key)
        self._fast[key] = cell
        return cell

    def _scaled2(
        self, x: Sequence[float], rotation: tuple[float, float] | None
    ) -> list[float] | None:
        """The fast 2D cast in units of the range; None where the general path decides."""
        x0, x1 = x[0], x[1]
        (lo0, lo1), (hi0, hi1) = self._lo_t, self._hi_t
        if not (lo0 < x0 < hi0 and lo1 < x1 < hi1):
            return None
        inv = self._inv_size
        key = (math.floor((x0 - lo0) * inv), math.floor((x1 - lo1) * inv))
        cell = self._fast.get(key) or self._fast_cell(key)
        for a0, a1, b0, b1 in cell.boxes:
            if a0 <= x0 <= b0 and a1 <= x1 <= b1:
                return None
        o0, o1 = cell.origin
        p0, p1 = x0 - o0, x1 - o1
        c, s = rotation if rotation is not None else (1.0, 0.0)
        v = [c, s, p0 * c + p1 * s, p1 * c - p0 * s, p0, p1, 1.0, p0 * p0 + p1 * p1]
        return cell.solve(np.array(v))

    def _scaled3(self, x: Sequence[float]) -> list[float] | None:
        """The fast 3D cast in units of the range; None where the general path decides."""
        x0, x1, x2 = x[0], x[1], x[2]
        (lo0, lo1, lo2), (hi0, hi1, hi2) = self._lo_t, self._hi_t
        if not (lo0 < x0 < hi0 and lo1 < x1 < hi1 and lo2 < x2 < hi2):
            return None
        inv = self._inv_size
        key = (
            math.floor((x0 - lo0) * inv),
            math.floor((x1 - lo1) * inv),
            math.floor((x2 - lo2) * inv),
        )
        cell = self._fast.get(key) or self._fast_cell(key)
        for a0, a1, a2, b0, b1, b2 in cell.boxes:
            if a0 <= x0 <= b0 and a1 <= x1 <= b1 and a2 <= x2 <= b2:
                return None
        o0, o1, o2 = cell.origin
        p0, p1, p2 = x0 - o0, x1 - o1, x2 - o2
        return cell.solve(np.array([1.0, p0, p1, p2, p0 * p0 + p1 * p1 + p2 * p2]))

    def cast_general(
        self, x: Sequence[float], rotation: tuple[float, float] | None = None
    ) -> FloatArray:
        """The reference cast: per-kind slab, quadratic and edge tests over the cell's
        obstacles, in metres (the fast path falls back to it for points outside the open bounds or
        inside a 2D box, and the tests compare against it)."""
        p = np.array(x, dtype=float)
        u = self.directions
        if rotation is not None:
            c, s = rotation
            u = u @ np.array([[c, s], [-s, c]])
        # The offset keeps axis-aligned rays finite (1e15 stands for infinity here).
        inv = (1.0 / (u + 1e-15))[:, None, None, :]
        cell = self._cell(x)
        # Column 0 is the world's bounds (the ray leaves them at "far"), the others the boxes
        # (the ray enters at "near" if it meets them at all).
        t = (cell.corners - p) * inv
        far = t.max(axis=1).min(axis=2)
        best = np.minimum(far[:, 0], self.max_range)
        if cell.corners.shape[1] > 1:
            near = np.maximum(t.min(axis=1).max(axis=2)[:, 1:], 0.0)
            best = np.minimum(best, np.where(far[:, 1:] >= near, near, np.inf).min(axis=1))
        if cell.ball_c is not None and cell.ball_r2 is not None:
            oc = p - cell.ball_c
            b = u @ oc.T
            disc = b * b - ((oc * oc).sum(axis=1) - cell.ball_r2)
            root = np.sqrt(np.maximum(disc, 0.0))
            t_in = -b - root
            hit = (disc >= 0.0) & (t_in >= 0.0)
            best = np.minimum(best, np.where(hit, t_in, np.inf).min(axis=1))
        if cell.edge_a is not None and cell.edge_e is not None:
            ap, e = cell.edge_a - p, cell.edge_e
            den = np.outer(u[:, 0], e[:, 1]) - np.outer(u[:, 1], e[:, 0])
            den = np.where(np.abs(den) < 1e-15, 1e-15, den)
            t = (ap[:, 0] * e[:, 1] - ap[:, 1] * e[:, 0]) / den
            along = (np.outer(u[:, 1], ap[:, 0]) - np.outer(u[:, 0], ap[:, 1])) / den
            ok = (t >= 0.0) & (along >= 0.0) & (along <= 1.0)
            best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
        return best

    def _boxes_meeting(self, cell_lo: FloatArray, cell_hi: FloatArray) -> list[tuple[float, ...]]:
        """``(lo_0, .., hi_0, ..)`` of the closed boxes that meet the closed cell: a ray from a
        point in one (or on its surface) takes the general path."""
        meet = gap(self._box_lo, self._box_hi, cell_lo, cell_hi) <= 0.0
        return [tuple(b) for b in np.hstack([self._box_lo, self._box_hi])[meet].tolist()]

    def _segments(self) -> tuple[FloatArray, FloatArray]:
        """2D: start points and edge vectors of the bounds, box (counter-clockwise) and polygon
        edges."""
        corners = [np.stack([self._lo, self._hi])] + [
            np.stack([lo, hi]) for lo, hi in zip(self._box_lo, self._box_hi, strict=True)
        ]
        starts, ends = [self._edge_a], [self._edge_b]
        for (x0, y0), (x1, y1) in corners:
            ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
            starts.append(ring)
            ends.append(np.roll(ring, -1, axis=0))
        a = np.concatenate(starts)
        return a, np.concatenate(ends) - a

    def _slabs(self) -> tuple[FloatArray, FloatArray]:
        """3D: corners of the boxes and of six slabs covering the outside of the bounds (as far
        as a ray can reach)."""
        lo, hi, m = self._lo, self._hi, 2.0 * self.max_range
        los, his = [self._box_lo], [self._box_hi]
        for axis in range(self.dim):
            for side in (lo, hi):
                a, b = lo - m, hi + m
                if side is lo:
                    b = b.copy()
                    b[axis] = lo[axis]
                else:
                    a = a.copy()
                    a[axis] = hi[axis]
                los.append(a[None])
                his.append(b[None])
        return np.concatenate(los), np.concatenate(his)
