"""The fast path of ``envs.rays.RayCaster``: per grid cell, every cast is one matrix product
of the pose features and a few elementwise numpy calls (2D: segments and balls; 3D: boxes and
balls)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from envs.rays import RayCaster

FloatArray = NDArray[np.float64]

_SLACK = 1e-9
"""Slack of the edge parameter test in 2D: a ray through a vertex hits either edge despite
rounding."""
_TINY = 1e-200
"""Added to every ray/edge denominator: a ray parallel to an edge divides by it, not by 0."""
_BIG = 1e200
"""Turns a negative ball discriminant (the ray misses the ball) into a failed test."""


def gap(lo: FloatArray, hi: FloatArray, cell_lo: FloatArray, cell_hi: FloatArray) -> FloatArray:
    """Euclidean distance between boxes ``[lo, hi]`` ``(n, d)`` and the cell box."""
    gap = np.maximum(0.0, np.maximum(cell_lo - hi, lo - cell_hi))
    return np.sqrt((gap * gap).sum(axis=1))


class FastCell:
    """One grid cell of the fast path. Everything a cast computes that is linear in the pose
    features ``v`` (see :meth:`RayCaster.cast_scaled`) is the single product ``v @ matrix``,
    written into views of ``lin``; the rest is a handful of elementwise numpy calls.

    Coordinates are relative to the cell centre (small numbers, little rounding) and distances
    are in units of the ray range. ``t`` holds a candidate distance per ray and obstacle
    feature, ``s`` a test value: a candidate counts when ``t >= 0`` and ``s <= threshold``. The
    last column is the range itself (``t = 1``, always counts).
    """

    def __init__(self, origin: list[float], rows: int, columns: int, count: int) -> None:
        self.origin = origin
        self.matrix = np.zeros((rows, columns))
        self.lin = np.zeros(columns)
        self.count = count
        self.threshold = 0.0
        self.boxes: list[tuple[float, ...]] = []
        """The closed boxes meeting the cell, see ``RayCaster._boxes_meeting``."""
        self._used = 0

    def block(self, *shape: int) -> tuple[FloatArray, FloatArray]:
        """The next block of columns: its ``(rows, *shape)`` part of the matrix (to fill) and
        its ``shape`` view of ``lin``."""
        size = math.prod(shape)
        part = slice(self._used, self._used + size)
        self._used += size
        rows = self.matrix.shape[0]
        return self.matrix[:, part].reshape(rows, *shape), self.lin[part].reshape(shape)

    def candidates(self, *widths: int) -> list[FloatArray]:
        """Allocate ``t`` and ``s`` (stacked as ``ts``) and return the ``(2, count, width)``
        column blocks of ``ts`` of ``widths``."""
        total = sum(widths)
        self.ts = np.zeros((2, self.count, total + 1))
        self.t, self.s = self.ts[0], self.ts[1]
        self.t[:, -1] = 1.0
        self.bad = np.zeros(self.t.shape, dtype=bool)
        self.bad_s = np.zeros(self.t.shape, dtype=bool)
        out, start = [], 0
        for w in widths:
            out.append(self.ts[:, :, start : start + w])
            start += w
        return out

    def balls(self, bn: FloatArray, kk: FloatArray) -> None:
        """Ray/ball views: ``bn`` (count, balls) distance to the point of closest approach,
        ``kk`` (balls,) squared distance to the centre minus squared radius."""
        self.bn, self.kk = bn, kk
        self.disc = np.zeros(bn.shape)

    def finish(self) -> list[float]:
        """Per ray, the least candidate that counts."""
        t = self.t
        np.less(t, 0.0, out=self.bad)
        np.greater(self.s, self.threshold, out=self.bad_s)
        np.logical_or(self.bad, self.bad_s, out=self.bad)
        np.putmask(t, self.bad, math.inf)
        result: list[float] = t.min(axis=1).tolist()
        return result

    def solve_balls(self, t_ball: FloatArray, s_ball: FloatArray) -> None:
        """Entry distance ``bn - sqrt(disc)``, counting only if ``disc >= 0``."""
        disc, bn = self.disc, self.bn
        np.multiply(bn, bn, out=disc)
        np.subtract(disc, self.kk, out=disc)
        np.multiply(disc, -_BIG, out=s_ball)
        np.abs(disc, out=disc)
        np.sqrt(disc, out=disc)
        np.subtract(bn, disc, out=t_ball)


class FastCell2(FastCell):
    """2D: segments (bounds, box and polygon edges) and balls; ``v = (c, s, a, b, p0, p1, 1,
    |p|^2)`` with ``p`` the robot point, ``(c, s)`` the heading and ``(a, b)`` the point in the
    robot frame."""

    def __init__(self, caster: RayCaster, key: tuple[int, ...]) -> None:
        size, rng = caster._cell_size, caster.max_range
        cell_lo = caster._lo + np.asarray(key, dtype=float) * size
        cell_hi = cell_lo + size
        o = (cell_lo + cell_hi) / 2.0
        a, e = caster._segments()
        keep = gap(np.minimum(a, a + e), np.maximum(a, a + e), cell_lo, cell_hi) <= rng * 1.000001
        a, e = a[keep] - o, e[keep]
        c, r = caster._ball_c, caster._ball_r
        near = gap(c - r[:, None], c + r[:, None], cell_lo, cell_hi) <= rng * 1.000001
        c, r = c[near] - o, r[near]
        k, ns, nb = caster.count, len(a), len(c)
        super().__init__(o.tolist(), 8, 3 * k * ns + k * nb + nb, k)
        self.threshold = 0.5 + _SLACK
        d0, d1 = caster.directions[:, :1], caster.directions[:, 1:]
        e0, e1 = e[:, 0], e[:, 1]
        m0, m1 = a[:, 0] + 0.5 * e0, a[:, 1] + 0.5 * e1
        den_m, self.den = self.block(k, ns)
        den_m[0], den_m[1], den_m[6] = rng * (d0 * e1 - d1 * e0), -rng * (d0 * e0 + d1 * e1), _TINY
        # Numerators of the distance along the ray (the same for every ray) and of the edge
        # parameter, divided by ``den`` in one call.
        num_m, self.num = self.block(2, k, ns)
        tn_m, sn_m = num_m[:, 0], num_m[:, 1]
        tn_m[6], tn_m[4], tn_m[5] = a[:, 0] * e1 - a[:, 1] * e0, -e1, e0
        sn_m[0], sn_m[1] = rng * (m0 * d1 - m1 * d0), rng * (m0 * d0 + m1 * d1)
        sn_m[2], sn_m[3] = -rng * d1, rng * d0
        bn_m, bn = self.block(k, nb)
        c0, c1 = c[:, 0], c[:, 1]
        bn_m[0], bn_m[1] = (c0 * d0 + c1 * d1) / rng, (d0 * c1 - d1 * c0) / rng
        bn_m[2], bn_m[3] = -d0 / rng, -d1 / rng
        kk_m, kk = self.block(nb)
        inv2 = 1.0 / (rng * rng)
        kk_m[7], kk_m[4], kk_m[5] = inv2, -2.0 * c0 * inv2, -2.0 * c1 * inv2
        kk_m[6] = (c0 * c0 + c1 * c1 - r * r) * inv2
        self.balls(bn, kk)
        self.ts_seg, ts_ball = self.candidates(ns, nb)
        self.s_seg, self.t_ball, self.s_ball = self.ts_seg[1], ts_ball[0], ts_ball[1]
        self.boxes = caster._boxes_meeting(cell_lo, cell_hi)

    def solve(self, v: FloatArray) -> list[float]:
        np.matmul(v, self.matrix, out=self.lin)
        if self.den.size:
            np.divide(self.num, self.den, out=self.ts_seg)
            np.abs(self.s_seg, out=self.s_seg)
        if self.kk.size:
            self.solve_balls(self.t_ball, self.s_ball)
        return self.finish()


class FastCell3(FastCell):
    """3D: slabs (boxes and six half-spaces outside the bounds) and balls; ``v = (1, p0, p1, p2,
    |p|^2)``. The rays keep their world-frame directions, so the slab entry and exit planes of
    every ray are fixed."""

    def __init__(self, caster: RayCaster, key: tuple[int, ...]) -> None:
        size, rng = caster._cell_size, caster.max_range
        cell_lo = caster._lo + np.asarray(key, dtype=float) * size
        cell_hi = cell_lo + size
        o = (cell_lo + cell_hi) / 2.0
        lo, hi = caster._slabs()
        keep = gap(lo, hi, cell_lo, cell_hi) <= rng * 1.000001
        lo, hi = lo[keep] - o, hi[keep] - o
        c, r = caster._ball_c, caster._ball_r
        close = gap(c - r[:, None], c + r[:, None], cell_lo, cell_hi) <= rng * 1.000001
        c, r = c[close] - o, r[close]
        k, nx, nb = caster.count, len(lo), len(c)
        super().__init__(o.tolist(), 5, 6 * k * nx + k * nb + nb, k)
        inv = (caster._inv_dir / rng).T[:, :, None]
        forward = (caster._inv_dir >= 0.0).T[:, :, None]
        # (axis, entry or minus exit, ray, slab): reduced by hand over the three axes, entry
        # and exit at once (faster than a numpy reduction over a length-3 axis).
        slab_m, slab = self.block(3, 2, k, nx)
        slab_m[0, :, 0] = np.where(forward, lo.T[:, None, :], hi.T[:, None, :]) * inv
        slab_m[0, :, 1] = -np.where(forward, hi.T[:, None, :], lo.T[:, None, :]) * inv
        for axis in range(3):
            slab_m[1 + axis, axis, 0] = -inv[axis]
            slab_m[1 + axis, axis, 1] = inv[axis]
        self.slab = list(slab)
        d = caster.directions
        bn_m, bn = self.block(k, nb)
        bn_m[0] = d @ c.T / rng
        for axis in range(3):
            bn_m[1 + axis] = -d[:, axis : axis + 1] / rng
        kk_m, kk = self.block(nb)
        inv2 = 1.0 / (rng * rng)
        kk_m[4], kk_m[0] = inv2, ((c * c).sum(axis=1) - r * r) * inv2
        for axis in range(3):
            kk_m[1 + axis] = -2.0 * c[:, axis] * inv2
        self.balls(bn, kk)
        self.ts_box, ts_ball = self.candidates(nx, nb)
        self.t_box, self.s_box = self.ts_box[0], self.ts_box[1]
        self.t_ball, self.s_ball = ts_ball[0], ts_ball[1]
        self.boxes = caster._boxes_meeting(cell_lo, cell_hi)

    def solve(self, v: FloatArray) -> list[float]:
        np.matmul(v, self.matrix, out=self.lin)
        if self.t_box.size:
            (x0, x1, x2), ts, t, s = self.slab, self.ts_box, self.t_box, self.s_box
            np.maximum(x0, x1, out=ts)
            np.maximum(ts, x2, out=ts)  # t: latest entry, s: minus the earliest exit
            np.maximum(t, 0.0, out=t)
            np.add(t, s, out=s)  # entry - exit <= 0: the ray meets the box
        if self.kk.size:
            self.solve_balls(self.t_ball, self.s_ball)
        return self.finish()
