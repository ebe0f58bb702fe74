"""The ``robot:`` section of a mission document: dynamics model, start state, size, parameters.

Validated with pydantic and free of heavy imports (no torch, no pybullet) so that the CLI and the
API can check a mission without loading a simulator.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

RobotModel = Literal["unicycle", "racecar", "quadrotor", "point"]

START_LAYOUTS: dict[str, tuple[tuple[str, ...], ...]] = {
    "unicycle": (("x", "y"), ("x", "y", "theta")),
    "racecar": (("x", "y"), ("x", "y", "theta")),
    "quadrotor": (("x", "y", "z"), ("x", "y", "z", "yaw")),
    "point": (("x", "y"), ("x", "y", "z")),
}
"""Accepted layouts of ``start`` per model: position first, then an optional heading."""

WORKSPACE_DIM: dict[str, int | None] = {"unicycle": 2, "racecar": 2, "quadrotor": 3, "point": None}
"""Workspace dimension of each model; ``None``: given by the length of ``start``."""


def layout_text(model: str) -> str:
    """Human description of the start layouts of ``model``, e.g. ``[x, y] or [x, y, theta]``."""
    return " or ".join("[" + ", ".join(names) + "]" for names in START_LAYOUTS[model])


class RobotSpec(BaseModel):
    """The robot: which dynamics, where it starts, how big it is."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    model: RobotModel = Field(
        description="Dynamics model: 'unicycle' and 'racecar' drive in 2D, 'quadrotor' flies in "
        "3D, 'point' is a holonomic point robot in 2D or 3D."
    )
    start: list[float] = Field(
        description="Start state. unicycle/racecar: [x, y] or [x, y, theta]; quadrotor: "
        "[x, y, z] or [x, y, z, yaw]; point: [x, y] or [x, y, z]. Angles in radians, "
        "default 0."
    )
    radius: float = Field(
        0.2,
        ge=0,
        description="Radius of the robot's bounding disc/sphere: obstacles are inflated by it "
        "for planning and collision checks.",
    )
    params: dict[str, float] = Field(
        default_factory=dict,
        description="Model parameters by name (speed and acceleration limits, time step, ...); "
        "each model documents its own names and defaults.",
    )

    @field_validator("start")
    @classmethod
    def _start_layout(cls, start: list[float], info: ValidationInfo) -> list[float]:
        model = info.data.get("model")
        if model is None:
            return start
        if len(start) not in {len(names) for names in START_LAYOUTS[model]}:
            raise PydanticCustomError(
                "start_layout",
                "a {model} starts at {layout}, got {n} numbers",
                {"model": model, "layout": layout_text(model), "n": len(start)},
            )
        return start

    @field_validator("params")
    @classmethod
    def _known_params(cls, params: dict[str, float], info: ValidationInfo) -> dict[str, float]:
        model = info.data.get("model")
        if model is None:
            return params
        from envs.robots import RobotConfigError, robot_params

        try:
            robot_params(model, params)
        except RobotConfigError as error:
            raise PydanticCustomError(
                "robot_params", "{reason}", {"reason": error.reason}
            ) from None
        return params

    @property
    def workspace_dim(self) -> int:
        """Dimension of the workspace the robot moves in (2 or 3)."""
        dim = WORKSPACE_DIM[self.model]
        return len(self.start) if dim is None else dim

    def position(self) -> np.ndarray:
        """The start's position part (the first ``workspace_dim`` numbers) as a float array."""
        return np.asarray(self.start[: self.workspace_dim], dtype=float)
