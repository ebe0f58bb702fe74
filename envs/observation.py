"""The navigation env's observation: robot state, progress index, next r-balls, optional rays.

A flat float32 vector, every entry in ``[-1, 1]``, laid out as (``d`` is the workspace
dimension, ``n`` the robot's ``state_dim``, ``m`` the number of r-balls, ``k`` = ``lookahead``):

====================  =======  ===========================================================
slice                 length   content
====================  =======  ===========================================================
``[0, n)``            n        ``robot.observation()`` mapped affinely from
                               ``[state_low, state_high]`` to ``[-1, 1]``
``[n]``               1        progress ``(i_t + 1) / m``: 0 before the first ball, 1 in the
                               last (``i_t`` is the progress index, -1 before any ball)
``[n+1, n+1+k*d)``    k * d    ``"guided"`` only: centres of balls ``i_t+1 .. i_t+k`` (the last
                               ball repeated past the end) minus the robot position, divided
                               by ``lookahead_range`` and clipped to ``[-1, 1]``; rotated into
                               the robot frame (x ahead, y left) for robots that steer by
                               heading (unicycle, racecar), in the world frame for robots
                               commanded in the world frame (point, quadrotor)
``[.., +rays)``       rays     distance along each ray to the nearest obstacle surface or
                               world boundary divided by ``ray_range``, clipped to ``[0, 1]``
====================  =======  ===========================================================

``"paper"`` drops the ball block: the bare product state ``(s_t, i_t)`` of Cai et al.
Rays start at the robot's point (obstacles are not inflated by its radius). In 2D they are
``rays`` directions evenly spaced over the full turn, starting straight ahead for heading
robots (robot frame) or along +x; in 3D they are a Fibonacci sphere of directions in the world
frame. The progress index belongs to the product state, so the reward stays Markovian in it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from envs.robots import Robot
from planner.shapes import Ball, Box, Polygon
from planner.world import World

ObservationMode = Literal["guided", "paper"]

HEADING_FEATURES: dict[str, tuple[int, int]] = {"unicycle": (2, 3), "racecar": (2, 3)}
"""Models steered by heading, with the indices of ``cos theta`` and ``sin theta`` in their
``observation()`` (both document ``(x, y, cos theta, sin theta, ...)``)."""

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]


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
    """The obstacles a ray cast from one grid cell can reach, stacked by kind."""

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

    Only obstacles whose bounding box comes within ``max_range`` of the robot's grid cell (cell
    size ``max_range / 2``) are cast against; those sets are built lazily per cell. A ray that
    starts inside an obstacle reads 0 for a box and a polygon and the exit distance for a ball
    (the robot has crashed then anyway).
    """

    def __init__(self, world: World, count: int, max_range: float) -> None:
        self.dim = world.dim
        self.count = count
        self.max_range = float(max_range)
        self.directions = ray_directions(self.dim, count)
        self._lo = np.asarray(world.bounds[:, 0], dtype=float)
        self._hi = np.asarray(world.bounds[:, 1], dtype=float)
        self._origin = self._lo.tolist()
        self._cell_size = self.max_range / 2.0
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

    def _cell(self, x: Sequence[float]) -> _Cell:
        size = self._cell_size
        key = tuple([math.floor((v - o) / size) for v, o in zip(x, self._origin, strict=False)])
        found = self._cells.get(key)
        if found is None:
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


class ObservationBuilder:
    """Builds the observation vector of the module docstring from the robot's raw features, its
    position and the progress index; the layout is fixed at construction."""

    def __init__(
        self,
        robot: Robot,
        centers: np.ndarray,
        mode: ObservationMode,
        lookahead: int,
        lookahead_range: float,
        rays: RayCaster | None,
    ) -> None:
        low = robot.state_low.astype(np.float64)
        high = robot.state_high.astype(np.float64)
        span = high - low
        self._scale = [2.0 / s if s > 0 else 0.0 for s in span.tolist()]
        self._offset = [
            -(h + lo) / s if s > 0 else 0.0
            for lo, h, s in zip(low, high, span.tolist(), strict=True)
        ]
        self.state_dim = robot.state_dim
        self.dim = robot.workspace_dim
        self.num_balls = len(centers)
        self._inv_m = 1.0 / self.num_balls
        self.lookahead = lookahead if mode == "guided" else 0
        self._inv_range = 1.0 / lookahead_range
        self.heading = HEADING_FEATURES.get(robot.name)
        flat = np.asarray(centers, dtype=float)
        # _ahead[i + 1]: the centres of the balls after progress index i, as tuples.
        self._ahead: list[list[tuple[float, ...]]] = []
        for i in range(-1, self.num_balls):
            idx = np.minimum(np.arange(i + 1, i + 1 + self.lookahead), self.num_balls - 1)
            self._ahead.append([tuple(c) for c in flat[idx].tolist()])
        self.rays = rays
        self.size = self.state_dim + 1 + self.lookahead * self.dim + (rays.count if rays else 0)
        self.space = spaces.Box(-1.0, 1.0, shape=(self.size,), dtype=np.float32)

    def build(self, raw: Float32Array, x: Sequence[float], index: int) -> Float32Array:
        """The observation for robot features ``raw``, position ``x`` and progress ``index``."""
        values = raw.tolist()
        out = [v * s + o for v, s, o in zip(values, self._scale, self._offset, strict=False)]
        out.append((index + 1) * self._inv_m)
        heading = self.heading
        rotation: tuple[float, float] | None = None
        if heading is not None:
            rotation = (values[heading[0]], values[heading[1]])
        if self.lookahead:
            inv = self._inv_range
            if self.dim == 2:
                x0, x1 = x[0], x[1]
                c, s = rotation if rotation is not None else (1.0, 0.0)
                for cx, cy in self._ahead[index + 1]:
                    dx, dy = cx - x0, cy - x1
                    u, v = (c * dx + s * dy) * inv, (c * dy - s * dx) * inv
                    out.append(u if -1.0 <= u <= 1.0 else (1.0 if u > 0.0 else -1.0))
                    out.append(v if -1.0 <= v <= 1.0 else (1.0 if v > 0.0 else -1.0))
            else:
                for centre in self._ahead[index + 1]:
                    for cj, xj in zip(centre, x, strict=False):
                        u = (cj - xj) * inv
                        out.append(u if -1.0 <= u <= 1.0 else (1.0 if u > 0.0 else -1.0))
        if self.rays is not None:
            ranges = self.rays.cast(x, rotation if self.dim == 2 else None)
            out.extend(np.clip(ranges * (1.0 / self.rays.max_range), 0.0, 1.0).tolist())
        return np.array(out, dtype=np.float32)
