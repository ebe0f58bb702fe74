"""The robot interface shared by every dynamics model, its parameter base and its fast collider.

A robot is a black box to the learner: it is reset at a workspace point, stepped with an action
in ``[-1, 1]^action_dim`` and observed through ``observation()`` (float32, ``state_dim`` long,
always inside ``[state_low, state_high]``). The planner only needs ``position()``, the projection
of the state into the workspace, and ``collided()``.

Actions outside ``[-1, 1]`` are rejected with ``ValueError`` instead of being clipped: a policy
that emits them has a bug (stable-baselines3 clips to the action space itself), and a silent clip
would hide it.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from planner.errors import FieldError
from planner.geometry.shapes import Ball, Box, Shape
from planner.geometry.world import World

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]


class RobotConfigError(FieldError, ValueError):
    """A robot that cannot be built: unknown model or parameter, bad value, wrong world.

    ``field`` names the culprit relative to the ``robot:`` section (``model``, ``radius``,
    ``params.max_speed``, ``world``) so the spec layer can turn it into a full field path.
    """


@dataclass(frozen=True)
class RobotParams:
    """Base of the per-model parameter dataclasses: every field must be a finite number.

    Subclasses declare their fields with defaults and a docstring each, and add range checks in
    ``check`` (raising through ``require``).
    """

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise RobotConfigError(f"params.{f.name}", f"must be a number, got {value!r}")
            if not math.isfinite(value):
                raise RobotConfigError(f"params.{f.name}", f"must be finite, got {value}")
            if f.type in ("int", int):
                if value != int(value):
                    raise RobotConfigError(f"params.{f.name}", f"must be an integer, got {value}")
                object.__setattr__(self, f.name, int(value))
        self.check()

    def check(self) -> None:
        """Range checks of the model; the base accepts every finite value."""

    def min_turning_radius(self) -> float:
        """The tightest turn of the robot's workspace point in metres (0: it can turn on the
        spot, or steers freely in every direction)."""
        return 0.0

    def require(self, ok: bool, name: str, message: str) -> None:
        """Raise ``RobotConfigError`` on ``params.<name>`` unless ``ok``."""
        if not ok:
            raise RobotConfigError(f"params.{name}", f"{message}, got {getattr(self, name)}")


class PointCollider:
    """Exact test "is this point within ``radius`` of an obstacle, or of the bounds?".

    Agrees with ``World.in_collision(points, clearance=radius)`` (obstacles inflated by the
    Minkowski sum with a ball, boundary counted as collision) but answers one point in about a
    microsecond: boxes and balls are tested in plain float arithmetic, and a uniform grid built
    once per robot keeps only the obstacles whose inflated bounding box meets the point's cell.
    Other shapes (polygons) fall back to their own ``contains``.
    """

    def __init__(self, world: World, radius: float) -> None:
        bounds = np.asarray(world.bounds, dtype=float)
        self.dim = int(bounds.shape[0])
        self.radius = float(radius)
        self._lo = tuple(float(v) + self.radius for v in bounds[:, 0])
        self._hi = tuple(float(v) - self.radius for v in bounds[:, 1])
        obstacles = tuple(world.obstacles)
        per_axis = max(1, min(64, 2 * math.ceil(len(obstacles) ** (1.0 / self.dim))))
        self._origin = tuple(float(v) for v in bounds[:, 0])
        extent = bounds[:, 1] - bounds[:, 0]
        self._cells = per_axis
        self._inv = tuple(per_axis / float(e) for e in extent)
        self._grid: dict[tuple[int, ...], list[tuple[Any, ...]]] = {}
        for shape in obstacles:
            entry = self._entry(shape)
            lo, hi = shape.bounding_box()
            first = self._cell(tuple(float(v) - self.radius for v in lo))
            last = self._cell(tuple(float(v) + self.radius for v in hi))
            for key in np.ndindex(*(b - a + 1 for a, b in zip(first, last, strict=True))):
                cell = tuple(a + k for a, k in zip(first, key, strict=True))
                self._grid.setdefault(cell, []).append(entry)

    def _entry(self, shape: Shape) -> tuple[Any, ...]:
        r = self.radius
        if isinstance(shape, Box):
            return ("box", tuple(shape.lo.tolist()), tuple(shape.hi.tolist()), r * r)
        if isinstance(shape, Ball):
            return ("ball", tuple(shape.center.tolist()), (shape.radius + r) ** 2)
        return ("shape", shape, r)

    def _cell(self, x: Sequence[float]) -> tuple[int, ...]:
        top = self._cells - 1
        return tuple(
            min(top, max(0, int((v - o) * s)))
            for v, o, s in zip(x, self._origin, self._inv, strict=True)
        )

    def hits(self, x: Sequence[float]) -> bool:
        """True if the disc/sphere of ``radius`` at ``x`` meets an obstacle or leaves the bounds."""
        for v, lo, hi in zip(x, self._lo, self._hi, strict=True):
            if not lo <= v <= hi:
                return True
        for entry in self._grid.get(self._cell(x), ()):
            kind = entry[0]
            if kind == "box":
                d2 = 0.0
                for v, lo, hi in zip(x, entry[1], entry[2], strict=True):
                    gap = lo - v if v < lo else (v - hi if v > hi else 0.0)
                    d2 += gap * gap
                if d2 <= entry[3]:
                    return True
            elif kind == "ball":
                d2 = 0.0
                for v, c in zip(x, entry[1], strict=True):
                    d2 += (v - c) * (v - c)
                if d2 <= entry[2]:
                    return True
            elif bool(entry[1].contains(np.array([x], dtype=float), margin=entry[2])[0]):
                return True
        return False


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped into ``[-pi, pi)``."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class Robot(ABC):
    """A dynamics model driven by normalised actions in a planner ``World``.

    Subclasses set the class attributes and implement ``_reset``, ``_step``, ``state``,
    ``observation`` and ``position``; this base validates inputs and tracks collisions.
    """

    name: ClassVar[str]
    """Model name used in mission files (``robot.model``)."""
    workspace_dims: ClassVar[tuple[int, ...]]
    """Workspace dimensions the model can live in."""
    params_type: ClassVar[type[RobotParams]]
    """The model's parameter dataclass."""

    workspace_dim: int
    """Dimension of the workspace (the world's)."""
    state_dim: int
    """Length of ``observation()``."""
    action_dim: int
    """Length of the action vector."""
    dt: float
    """Agent step in seconds: simulated time per ``step``."""
    state_low: Float32Array
    """Lower bounds of ``observation()`` (positions: the world bounds; velocities: limits)."""
    state_high: Float32Array
    """Upper bounds of ``observation()``."""

    def __init__(self, world: World, radius: float, params: RobotParams) -> None:
        dim = int(world.dim)
        if dim not in self.workspace_dims:
            allowed = " or ".join(f"{d}D" for d in self.workspace_dims)
            raise RobotConfigError(
                "model",
                f"a {self.name} robot moves in a {allowed} workspace, but the world is {dim}D",
            )
        radius = float(radius)
        if not (math.isfinite(radius) and radius >= 0.0):
            raise RobotConfigError("radius", f"must be a finite number >= 0, got {radius}")
        self.world = world
        self.radius = radius
        self.params = params
        self.workspace_dim = dim
        self.bounds = np.asarray(world.bounds, dtype=float)
        self._collider = PointCollider(world, radius)
        self._collided = False
        self._ready = False

    def reset(
        self, position: np.ndarray, rng: np.random.Generator, heading: float | None = None
    ) -> None:
        """Place the robot at rest at ``position`` (a workspace point) facing ``heading``.

        ``heading`` (radians, yaw about the vertical axis) is drawn uniformly from ``rng`` when
        None; models without a heading ignore it. Raises ``ValueError`` for a position of the
        wrong shape or outside the bounds. Starting inside an obstacle is allowed and reported
        by ``collided()``.
        """
        p = np.asarray(position, dtype=float)
        if p.shape != (self.workspace_dim,):
            raise ValueError(
                f"{self.name}: start position must have {self.workspace_dim} coordinates, "
                f"got shape {p.shape}"
            )
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{self.name}: start position must be finite, got {p.tolist()}")
        if np.any(p < self.bounds[:, 0]) or np.any(p > self.bounds[:, 1]):
            raise ValueError(
                f"{self.name}: start position {p.tolist()} is outside the world bounds "
                f"{self.bounds.tolist()}"
            )
        if heading is None:
            heading = float(rng.uniform(-math.pi, math.pi))
        elif not math.isfinite(heading):
            raise ValueError(f"{self.name}: heading must be finite, got {heading}")
        self._reset(p, wrap_angle(float(heading)), rng)
        self._ready = True
        self._collided = self._check_collision()

    def step(self, action: np.ndarray) -> None:
        """Advance ``dt`` seconds under ``action`` in ``[-1, 1]^action_dim``.

        Raises ``ValueError`` for an action of the wrong shape, with NaN, or outside ``[-1, 1]``
        (no silent clipping), and ``RuntimeError`` before the first ``reset``.
        """
        if not self._ready:
            raise RuntimeError(f"{self.name}: call reset() before step()")
        a = np.asarray(action, dtype=float)
        if a.shape != (self.action_dim,):
            raise ValueError(
                f"{self.name}: action must have shape ({self.action_dim},), got {a.shape}"
            )
        values: list[float] = a.tolist()
        for v in values:
            if not -1.0 <= v <= 1.0:
                if math.isnan(v):
                    raise ValueError(f"{self.name}: action contains NaN: {values}")
                raise ValueError(
                    f"{self.name}: action components must lie in [-1, 1] (actions are not "
                    f"clipped), got {values}"
                )
        self._collided = self._step(values)

    def collided(self) -> bool:
        """True if, after the last ``reset``/``step``, the robot (its disc/sphere of ``radius``)
        meets an obstacle or leaves the bounds; contact-based for the racecar."""
        return self._collided

    def close(self) -> None:
        """Release simulator resources; the robot must be built anew to be used again."""
        self._ready = False

    def project(self, states: np.ndarray) -> FloatArray:
        """Workspace points of states laid out as ``state`` (one ``(n,)`` or a batch ``(m, n)``).

        Every model stores its workspace position first, so this is the leading
        ``workspace_dim`` entries.
        """
        return np.asarray(states, dtype=float)[..., : self.workspace_dim].copy()

    def _check_collision(self) -> bool:
        return self._collider.hits(self.position().tolist())

    def _observation_bounds(
        self, low: Sequence[float], high: Sequence[float]
    ) -> tuple[Float32Array, Float32Array]:
        lo = np.asarray(low, dtype=np.float32)
        hi = np.asarray(high, dtype=np.float32)
        if lo.shape != (self.state_dim,) or hi.shape != (self.state_dim,):
            raise AssertionError(f"{self.name}: observation bounds do not match state_dim")
        return lo, hi

    def _clip_observation(self, values: Sequence[float]) -> Float32Array:
        """Observation features as float32, clipped into ``[state_low, state_high]`` so that they
        always lie in the observation space (a robot that just left the bounds is collided)."""
        obs = np.asarray(values, dtype=np.float32)
        return np.minimum(np.maximum(obs, self.state_low), self.state_high)

    @abstractmethod
    def _reset(self, position: FloatArray, heading: float, rng: np.random.Generator) -> None:
        """Set the state at rest at a validated ``position`` facing ``heading``."""

    @abstractmethod
    def _step(self, action: list[float]) -> bool:
        """Integrate one agent step under a validated action; return whether it collided."""

    @property
    @abstractmethod
    def state(self) -> FloatArray:
        """The full physical state (float64 copy), model-specific layout (see the model)."""

    @abstractmethod
    def observation(self) -> Float32Array:
        """Features for the learner: float32, ``state_dim`` long, in ``[state_low, state_high]``."""

    @abstractmethod
    def position(self) -> FloatArray:
        """The state projected into the workspace (``workspace_dim`` long)."""

    def heading(self) -> float:
        """Yaw (radians) as ``reset`` takes it, so that a pose can be restored; 0 for models
        without a heading."""
        return 0.0
