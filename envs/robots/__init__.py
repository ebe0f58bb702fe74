"""Robot dynamics models selectable by name (``robot.model`` in a mission file).

``make_robot(model, world, radius, params)`` builds one; ``robot_params(model, params)``
validates the parameters alone (for the spec layer, without building a simulator). Errors are
``RobotConfigError`` (a ``ValueError``) whose ``field`` names the culprit: ``model``,
``radius`` or ``params.<name>``.

Importing this package is light: the racecar imports PyBullet only when one is built.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from envs.robots.base import PointCollider, Robot, RobotConfigError, RobotParams
from envs.robots.point import PointParams, PointRobot
from envs.robots.quadrotor import Quadrotor, QuadrotorParams
from envs.robots.racecar import WHEEL_RADIUS, Racecar, RacecarParams
from envs.robots.unicycle import Unicycle, UnicycleParams
from planner.geometry.world import World

ROBOT_MODELS: Mapping[str, type[Robot]] = {
    "unicycle": Unicycle,
    "racecar": Racecar,
    "quadrotor": Quadrotor,
    "point": PointRobot,
}
"""Every model by its mission-file name."""

__all__ = [
    "ROBOT_MODELS",
    "PointCollider",
    "PointParams",
    "PointRobot",
    "Quadrotor",
    "QuadrotorParams",
    "Racecar",
    "RacecarParams",
    "Robot",
    "RobotConfigError",
    "RobotParams",
    "Unicycle",
    "UnicycleParams",
    "make_robot",
    "robot_class",
    "robot_params",
]


def robot_class(model: str) -> type[Robot]:
    """The class of ``model``; ``RobotConfigError`` on ``model`` if there is none."""
    try:
        return ROBOT_MODELS[model]
    except (KeyError, TypeError):
        known = ", ".join(sorted(ROBOT_MODELS))
        raise RobotConfigError("model", f"unknown robot model {model!r}; known: {known}") from None


def robot_params(model: str, params: Mapping[str, float] | None = None) -> RobotParams:
    """The validated parameter dataclass of ``model`` with ``params`` over its defaults.

    Raises ``RobotConfigError`` for an unknown model (field ``model``), an unknown parameter
    name or a bad value (field ``params.<name>``).
    """
    cls = robot_class(model).params_type
    known = [f.name for f in fields(cls)]
    values: dict[str, Any] = dict(params or {})
    for name in values:
        if name not in known:
            raise RobotConfigError(
                f"params.{name}",
                f"unknown parameter {name!r} for robot model {model!r}; known: {', '.join(known)}",
            )
    return cls(**values)


def make_robot(
    model: str, world: World, radius: float, params: Mapping[str, float] | None = None
) -> Robot:
    """Build a ``model`` robot of ``radius`` in ``world`` (a ``planner.geometry.world.World``).

    Raises ``RobotConfigError`` for an unknown model or parameter, a bad value, or a world whose
    dimension the model cannot move in. Call ``reset`` before stepping and ``close`` at the end.
    """
    cls = robot_class(model)
    return cls(world, radius, robot_params(model, params))


def nominal_speed(robot: Robot) -> float:
    """The robot's top speed in m/s (``max_speed``; racecar: wheel speed times radius)."""
    return top_speed(robot.params)


def top_speed(params: RobotParams) -> float:
    """The top speed in m/s of a robot of ``params`` (see ``nominal_speed``)."""
    if isinstance(params, RacecarParams):
        return float(params.max_wheel_speed * WHEEL_RADIUS)
    speed = getattr(params, "max_speed", None)
    return float(speed) if isinstance(speed, int | float) and speed > 0 else 1.0
