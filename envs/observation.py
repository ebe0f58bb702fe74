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

from collections.abc import Sequence
from typing import Literal

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from envs.rays import RayCaster
from envs.robots import Robot

ObservationMode = Literal["guided", "paper"]

HEADING_FEATURES: dict[str, tuple[int, int]] = {"unicycle": (2, 3), "racecar": (2, 3)}
"""Models steered by heading, with the indices of ``cos theta`` and ``sin theta`` in their
``observation()`` (both document ``(x, y, cos theta, sin theta, ...)``)."""

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]


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
            out.extend(self.rays.cast_scaled(x, rotation if self.dim == 2 else None))
        return np.array(out, dtype=np.float32)
