"""One region's membership and distance for a single point, fast.

An env asks, every step, whether the robot's point lies in its goal region and which regions
contain it. numpy costs microseconds per call on one point; plain float arithmetic costs a
fraction of one, so boxes and balls are tested that way and other shapes fall back on their own
(vectorised) methods.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from planner.geometry.shapes import Ball, Box, Shape


class RegionTest:
    """Scalar membership and distance of one workspace shape: plain float arithmetic for boxes
    and balls (a fraction of a microsecond), the shape's own methods otherwise."""

    def __init__(self, shape: Shape) -> None:
        self.shape = shape
        self.contains: Callable[[Sequence[float]], bool] = self._generic_contains
        """Whether a point lies in the shape (boundary included)."""
        if isinstance(shape, Box):
            lo, hi = tuple(shape.lo.tolist()), tuple(shape.hi.tolist())
            self._lo, self._hi = lo, hi
            if len(lo) == 2:
                (a0, a1), (b0, b1) = lo, hi
                self.contains = lambda x: a0 <= x[0] <= b0 and a1 <= x[1] <= b1
            else:
                (a0, a1, a2), (b0, b1, b2) = lo, hi
                self.contains = lambda x: a0 <= x[0] <= b0 and a1 <= x[1] <= b1 and a2 <= x[2] <= b2
        elif isinstance(shape, Ball):
            centre, radius = tuple(shape.center.tolist()), float(shape.radius)
            self._centre, self._radius = centre, radius
            self.contains = lambda x: math.dist(x, centre) <= radius

    def __reduce__(self) -> tuple[type[RegionTest], tuple[Shape]]:
        """Pickled as its shape (the fast tests are closures, rebuilt on unpickling)."""
        return RegionTest, (self.shape,)

    def _generic_contains(self, x: Sequence[float]) -> bool:
        return bool(self.shape.contains(np.array([x], dtype=float))[0])

    def distance(self, x: Sequence[float]) -> float:
        """Euclidean distance from ``x`` to the shape (0 inside)."""
        if isinstance(self.shape, Box):
            d2 = 0.0
            for v, a, b in zip(x, self._lo, self._hi, strict=False):
                gap = a - v if v < a else (v - b if v > b else 0.0)
                d2 += gap * gap
            return math.sqrt(d2)
        if isinstance(self.shape, Ball):
            return max(0.0, math.dist(x, self._centre) - self._radius)
        return float(self.shape.distance(np.array([x], dtype=float))[0])
