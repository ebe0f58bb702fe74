"""Kinematic unicycle: the fast 2D car-like default for training, tests and benchmarks.

The action ``(a_v, a_w)`` in ``[-1, 1]^2`` sets the forward speed and the turn rate for one agent
step. Forward speed is piecewise linear in ``a_v``: ``a_v * max_speed`` for ``a_v >= 0`` and
``a_v * max_reverse_speed`` below zero, so ``a_v = 0`` stops the robot and reversing can be
limited or forbidden (``max_reverse_speed = 0``: negative ``a_v`` means stand still). Turn rate is
``a_w * max_turn_rate`` (counter-clockwise positive). The motion over a step is integrated
exactly (a circular arc), so the result does not depend on a sub-step size.

State ``(x, y, theta)``; observation ``(x, y, cos theta, sin theta)``; ``position() = (x, y)``.
Collisions are checked at the end of every agent step; a step moves at most
``max_speed * dt``, so obstacles thinner than that minus twice the radius could be jumped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from envs.robots.base import Float32Array, FloatArray, Robot, RobotParams, wrap_angle
from planner.geometry.world import World


@dataclass(frozen=True)
class UnicycleParams(RobotParams):
    """Limits and time step of the kinematic unicycle."""

    max_speed: float = 1.0
    """Forward speed at ``a_v = 1`` in m/s."""
    max_reverse_speed: float = 0.3
    """Backward speed at ``a_v = -1`` in m/s; 0 forbids reversing."""
    max_turn_rate: float = 2.0
    """Turn rate at ``|a_w| = 1`` in rad/s."""
    dt: float = 0.1
    """Agent step in seconds."""

    def check(self) -> None:
        self.require(self.max_speed > 0.0, "max_speed", "must be > 0")
        self.require(self.max_reverse_speed >= 0.0, "max_reverse_speed", "must be >= 0")
        self.require(self.max_turn_rate > 0.0, "max_turn_rate", "must be > 0")
        self.require(self.dt > 0.0, "dt", "must be > 0")


class Unicycle(Robot):
    """Kinematic unicycle in 2D (see the module docstring for the action and state layout)."""

    name: ClassVar[str] = "unicycle"
    workspace_dims: ClassVar[tuple[int, ...]] = (2,)
    params_type: ClassVar[type[RobotParams]] = UnicycleParams

    def __init__(self, world: World, radius: float, params: UnicycleParams) -> None:
        super().__init__(world, radius, params)
        self.p = params
        self.state_dim = 4
        self.action_dim = 2
        self.dt = params.dt
        (x0, x1), (y0, y1) = self.bounds.tolist()
        self.state_low, self.state_high = self._observation_bounds(
            [x0, y0, -1.0, -1.0], [x1, y1, 1.0, 1.0]
        )
        self._x = self._y = self._theta = 0.0

    def _reset(self, position: FloatArray, heading: float, rng: np.random.Generator) -> None:
        self._x, self._y = float(position[0]), float(position[1])
        self._theta = heading

    def _step(self, action: list[float]) -> bool:
        p = self.p
        a_v, a_w = action
        v = a_v * (p.max_speed if a_v >= 0.0 else p.max_reverse_speed)
        w = a_w * p.max_turn_rate
        dt = p.dt
        theta = self._theta
        turn = w * dt
        if abs(turn) > 1e-9:
            r = v / w
            new_theta = theta + turn
            self._x += r * (math.sin(new_theta) - math.sin(theta))
            self._y += r * (math.cos(theta) - math.cos(new_theta))
            self._theta = wrap_angle(new_theta)
        else:
            self._x += v * dt * math.cos(theta)
            self._y += v * dt * math.sin(theta)
        return self._collider.hits((self._x, self._y))

    @property
    def state(self) -> FloatArray:
        """``(x, y, theta)`` with theta in ``[-pi, pi)``."""
        return np.array([self._x, self._y, self._theta])

    def observation(self) -> Float32Array:
        """``(x, y, cos theta, sin theta)``."""
        return self._clip_observation(
            (self._x, self._y, math.cos(self._theta), math.sin(self._theta))
        )

    def position(self) -> FloatArray:
        return np.array([self._x, self._y])

    def heading(self) -> float:
        return self._theta
