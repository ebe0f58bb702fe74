"""The ``world:`` section of a mission document, validated with pydantic.

A world is a 2D or 3D box of ``bounds`` holding obstacles and labelled regions, each written as
a one-key shape mapping (``{box: ...}``, ``{ball: ...}`` or ``{polygon: ...}``). The models here
check what can be checked without the robot or the task: shapes are well formed, every shape has
the dimension of the world, regions lie inside the bounds and their labels are legal atomic
propositions. ``WorldSpec.build`` turns a valid spec into the planner's ``World``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Annotated

import numpy as np
from pydantic import (
    AfterValidator,
    Field,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from planner.geometry.random_obstacles import generate_boxes
from planner.geometry.shape_spec import (
    SectionModel,
    ShapeSpec,
    check_dim,
    fmt_values,
    raise_problems,
)
from planner.geometry.shapes import Shape
from planner.geometry.world import World

LABEL_PATTERN = re.compile(r"[a-z_][a-z0-9_]*")
RESERVED_LABEL = "obstacle"


def _region_label(label: str) -> str:
    if not LABEL_PATTERN.fullmatch(label):
        raise PydanticCustomError(
            "region_label",
            "label '{label}' is not an atomic proposition: use lower-case letters, digits and "
            "'_', starting with a letter or '_'",
            {"label": label},
        )
    if label == RESERVED_LABEL:
        raise PydanticCustomError(
            "region_label",
            "'obstacle' is reserved: it holds inside every obstacle; name the region otherwise",
            {},
        )
    return label


RegionLabel = Annotated[str, AfterValidator(_region_label)]


class RandomObstaclesSpec(SectionModel):
    """Boxes scattered uniformly at random, away from the regions and the robot's start."""

    count: int = Field(
        ge=0, le=2000, description="Number of boxes to place (validation places them: <= 2000)."
    )
    size: list[float] = Field(description="Edge length of every box, one per axis (each > 0).")
    seed: int = Field(0, description="Seed of the generator: the same seed gives the same boxes.")
    clearance: float = Field(
        0.5,
        ge=0,
        description="Least distance between a box and any region or the robot's start.",
    )

    @field_validator("size")
    @classmethod
    def _positive(cls, size: list[float]) -> list[float]:
        check_dim(size, "size")
        if min(size) <= 0:
            raise PydanticCustomError("size", "every edge length must be > 0", {})
        return size


def _interval_list(bounds: list[list[float]]) -> list[list[float]]:
    if len(bounds) not in (2, 3):
        raise PydanticCustomError(
            "bounds",
            "give 2 (2D) or 3 (3D) intervals [lo, hi], got {n}",
            {"n": len(bounds)},
        )
    for axis, interval in enumerate(bounds):
        if len(interval) != 2:
            raise PydanticCustomError(
                "bounds",
                "interval {axis} must be [lo, hi], got {n} numbers",
                {"axis": axis, "n": len(interval)},
            )
        if interval[0] >= interval[1]:
            raise PydanticCustomError(
                "bounds",
                "interval {axis} must have lo < hi, got {interval}",
                {"axis": axis, "interval": fmt_values(interval)},
            )
    return bounds


class WorldSpec(SectionModel):
    """The workspace: bounds, obstacles (explicit and generated) and labelled regions."""

    bounds: Annotated[list[list[float]], AfterValidator(_interval_list)] = Field(
        description="One [lo, hi] interval per axis: 2 intervals for a 2D, 3 for a 3D workspace."
    )
    obstacles: list[ShapeSpec] = Field(
        default_factory=list,
        description="Shapes the robot must never touch; the label 'obstacle' holds inside them.",
    )
    random_obstacles: RandomObstaclesSpec | None = Field(
        None, description="Optional generator of extra box obstacles (seeded)."
    )
    regions: dict[RegionLabel, ShapeSpec] = Field(
        default_factory=dict,
        description="Labelled regions: label -> shape. The labels are the task's atomic "
        "propositions; regions may overlap and must lie inside the bounds.",
    )

    @property
    def dim(self) -> int:
        """Dimension of the workspace (2 or 3)."""
        return len(self.bounds)

    def bounds_array(self) -> np.ndarray:
        """The bounds as a (dim, 2) array of [lo, hi] rows."""
        return np.asarray(self.bounds, dtype=float)

    @model_validator(mode="after")
    def _consistent(self) -> WorldSpec:
        problems: list[tuple[str, str]] = []
        d = self.dim
        b = self.bounds_array()
        for i, shape in enumerate(self.obstacles):
            if shape.dim != d:
                problems.append((f"obstacles.{i}", f"is {shape.dim}D but the world is {d}D"))
                continue
            lo, hi = shape.bounding_box()
            if np.any(hi < b[:, 0]) or np.any(lo > b[:, 1]):
                problems.append((f"obstacles.{i}", "lies entirely outside the world bounds"))
        for label, shape in self.regions.items():
            if shape.dim != d:
                problems.append((f"regions.{label}", f"is {shape.dim}D but the world is {d}D"))
                continue
            lo, hi = shape.bounding_box()
            tol = 1e-9 * float(np.max(b[:, 1] - b[:, 0]))
            if np.any(lo < b[:, 0] - tol) or np.any(hi > b[:, 1] + tol):
                span = " x ".join(fmt_values(pair) for pair in zip(lo, hi, strict=True))
                problems.append(
                    (
                        f"regions.{label}",
                        f"lies outside the world bounds: it spans {span}, "
                        f"the bounds are {_fmt_bounds(b)}",
                    )
                )
        gen = self.random_obstacles
        if gen is not None:
            if len(gen.size) != d:
                problems.append(
                    ("random_obstacles.size", f"has {len(gen.size)} edge lengths for a {d}D world")
                )
            elif np.any(np.asarray(gen.size) > b[:, 1] - b[:, 0]):
                problems.append(("random_obstacles.size", "a box is larger than the world"))
        raise_problems(problems)
        return self

    def build(self, keep_clear: Sequence[np.ndarray] = ()) -> World:
        """The planner's world, with the generated obstacles kept away from ``keep_clear``.

        ``keep_clear`` holds points (typically the robot's start) that generated boxes must stay
        at least ``random_obstacles.clearance`` away from; they also avoid every region.
        Raises ``WorldError`` when the generator cannot place all its boxes.
        """
        bounds = self.bounds_array()
        obstacles: list[Shape] = [s.to_shape() for s in self.obstacles]
        regions: dict[str, Shape] = {label: s.to_shape() for label, s in self.regions.items()}
        gen = self.random_obstacles
        if gen is not None:
            obstacles.extend(
                generate_boxes(
                    bounds,
                    count=gen.count,
                    size=np.asarray(gen.size, dtype=float),
                    seed=gen.seed,
                    clearance=gen.clearance,
                    keep_clear=[np.asarray(p, dtype=float) for p in keep_clear],
                    avoid=list(regions.values()),
                )
            )
        return World(bounds, obstacles, regions)


def _fmt_bounds(bounds: np.ndarray) -> str:
    return "[" + ", ".join(fmt_values(row) for row in bounds) + "]"
