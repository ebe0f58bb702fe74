"""Point robot: a 2D or 3D double integrator for unit tests and simple baselines.

The action in ``[-1, 1]^d`` is an acceleration command scaled by ``max_accel`` per axis. Over an
agent step ``v' = v + (a - damping * v) dt``; ``v'`` is then scaled down to ``max_speed`` if
faster, and the position moves by the trapezoid ``(v + v') dt / 2``. The dimension is the
world's. State and observation ``(position, velocity)``; there is no heading (``reset`` ignores
it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from envs.robots.base import Float32Array, FloatArray, Robot, RobotParams
from planner.geometry.world import World


@dataclass(frozen=True)
class PointParams(RobotParams):
    """Limits and time step of the double integrator."""

    max_accel: float = 2.0
    """Acceleration at ``|a| = 1`` per axis, in m/s^2."""
    max_speed: float = 1.0
    """Speed limit (Euclidean norm of the velocity) in m/s."""
    damping: float = 0.0
    """Linear velocity damping in 1/s (0: none)."""
    dt: float = 0.1
    """Agent step in seconds."""

    def check(self) -> None:
        self.require(self.max_accel > 0.0, "max_accel", "must be > 0")
        self.require(self.max_speed > 0.0, "max_speed", "must be > 0")
        self.require(self.damping >= 0.0, "damping", "must be >= 0")
        self.require(self.dt > 0.0, "dt", "must be > 0")
        self.require(self.damping * self.dt < 1.0, "damping", "times dt must be < 1 (stability)")


class PointRobot(Robot):
    """Double integrator in the world's dimension (2 or 3)."""

    name: ClassVar[str] = "point"
    workspace_dims: ClassVar[tuple[int, ...]] = (2, 3)
    params_type: ClassVar[type[RobotParams]] = PointParams

    def __init__(self, world: World, radius: float, params: PointParams) -> None:
        super().__init__(world, radius, params)
        self.p = params
        d = self.workspace_dim
        self.state_dim = 2 * d
        self.action_dim = d
        self.dt = params.dt
        vmax = params.max_speed
        self.state_low, self.state_high = self._observation_bounds(
            self.bounds[:, 0].tolist() + [-vmax] * d, self.bounds[:, 1].tolist() + [vmax] * d
        )
        self._pos = [0.0] * d
        self._vel = [0.0] * d

    def _reset(self, position: FloatArray, heading: float, rng: np.random.Generator) -> None:
        self._pos = position.tolist()
        self._vel = [0.0] * self.workspace_dim

    def _step(self, action: list[float]) -> bool:
        p = self.p
        dt = p.dt
        new = [
            v + (a * p.max_accel - p.damping * v) * dt
            for v, a in zip(self._vel, action, strict=True)
        ]
        speed = math.sqrt(sum(v * v for v in new))
        if speed > p.max_speed:
            scale = p.max_speed / speed
            new = [v * scale for v in new]
        self._pos = [
            x + 0.5 * (v0 + v1) * dt for x, v0, v1 in zip(self._pos, self._vel, new, strict=True)
        ]
        self._vel = new
        return self._collider.hits(self._pos)

    @property
    def state(self) -> FloatArray:
        """``(position, velocity)``, ``2 * d`` long."""
        return np.array(self._pos + self._vel)

    def observation(self) -> Float32Array:
        """``(position, velocity)`` as float32."""
        return self._clip_observation(self._pos + self._vel)

    def position(self) -> FloatArray:
        return np.array(self._pos)
