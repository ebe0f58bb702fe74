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
from typing import Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from planner.geometry.random_obstacles import generate_boxes
from planner.geometry.shapes import Ball, Box, Polygon, Shape
from planner.geometry.world import World

LABEL_PATTERN = re.compile(r"[a-z_][a-z0-9_]*")
RESERVED_LABEL = "obstacle"
SHAPE_KINDS = ("box", "ball", "polygon")
PROBLEMS_ERROR = "ltlnav_problems"
"""pydantic error type whose ``ctx["problems"]`` lists ``(relative path, message)`` pairs."""


def raise_problems(problems: list[tuple[str, str]]) -> None:
    """Raise one pydantic error carrying several located problems found by a model validator.

    pydantic locates a model validator's error at the model itself; the problems keep their own
    sub-paths in the error context so that ``workers.mission`` can report each one exactly.
    """
    if problems:
        summary = "; ".join(f"{path}: {message}" if path else message for path, message in problems)
        raise PydanticCustomError(
            PROBLEMS_ERROR, "{summary}", {"problems": problems, "summary": summary}
        )


def _fmt(values: Sequence[float] | np.ndarray) -> str:
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def _check_dim(values: list[float], what: str) -> list[float]:
    if len(values) not in (2, 3):
        raise PydanticCustomError(
            "dimension",
            "{what} needs 2 (2D) or 3 (3D) numbers, got {n}",
            {"what": what, "n": len(values)},
        )
    return values


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class BoxBody(_Spec):
    """An axis-aligned box given by two opposite corners."""

    min: list[float] = Field(description="Lower corner: one coordinate per axis (2 or 3).")
    max: list[float] = Field(description="Upper corner: one coordinate per axis, each > min.")

    @model_validator(mode="after")
    def _corners(self) -> BoxBody:
        _check_dim(self.min, "min")
        if len(self.max) != len(self.min):
            raise PydanticCustomError(
                "dimension",
                "min has {a} coordinates but max has {b}",
                {"a": len(self.min), "b": len(self.max)},
            )
        for axis, (lo, hi) in enumerate(zip(self.min, self.max, strict=True)):
            if lo >= hi:
                raise PydanticCustomError(
                    "box_corners",
                    "min must be < max on every axis; axis {axis} has min {lo} >= max {hi}",
                    {"axis": axis, "lo": f"{lo:g}", "hi": f"{hi:g}"},
                )
        return self


class BoxSpec(_Spec):
    """``{box: {min: [...], max: [...]}}``: an axis-aligned rectangle (2D) or cuboid (3D)."""

    box: BoxBody = Field(description="The box's corners.")

    @property
    def dim(self) -> int:
        """Dimension of the shape (2 or 3)."""
        return len(self.box.min)

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners of the smallest axis-aligned box around the shape."""
        return np.asarray(self.box.min, dtype=float), np.asarray(self.box.max, dtype=float)

    def to_shape(self) -> Box:
        """The planner's geometric box."""
        lo, hi = self.bounding_box()
        return Box(lo, hi)


class BallBody(_Spec):
    """A disc (2D) or a sphere (3D)."""

    center: Annotated[list[float], AfterValidator(lambda v: _check_dim(v, "center"))] = Field(
        description="Centre: one coordinate per axis (2 or 3)."
    )
    radius: float = Field(gt=0, description="Radius in workspace units; must be > 0.")


class BallSpec(_Spec):
    """``{ball: {center: [...], radius: r}}``: a circle in 2D, a sphere in 3D."""

    ball: BallBody = Field(description="The ball's centre and radius.")

    @property
    def dim(self) -> int:
        """Dimension of the shape (2 or 3)."""
        return len(self.ball.center)

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners of the smallest axis-aligned box around the shape."""
        c = np.asarray(self.ball.center, dtype=float)
        return c - self.ball.radius, c + self.ball.radius

    def to_shape(self) -> Ball:
        """The planner's geometric ball."""
        return Ball(np.asarray(self.ball.center, dtype=float), float(self.ball.radius))


def _simple_polygon(vertices: list[list[float]]) -> list[list[float]]:
    """Check that the vertices describe a simple 2D polygon; a repeated closing vertex is dropped.

    Simplicity is decided by ``planner.geometry.shapes.Polygon`` itself, so a polygon accepted
    here is always accepted when the world is built.
    """
    for i, v in enumerate(vertices):
        if len(v) != 2:
            raise PydanticCustomError(
                "polygon_vertex",
                "polygons are 2D: vertex {i} has {n} coordinates instead of 2",
                {"i": i, "n": len(v)},
            )
    if len(vertices) > 3 and vertices[0] == vertices[-1]:
        vertices = vertices[:-1]
    if len(vertices) < 3:
        raise PydanticCustomError(
            "polygon_vertices",
            "a polygon needs at least 3 vertices, got {n}",
            {"n": len(vertices)},
        )
    try:
        Polygon(np.asarray(vertices, dtype=float))
    except ValueError as err:
        raise PydanticCustomError("polygon_simple", "{reason}", {"reason": str(err)}) from err
    return vertices


class PolygonSpec(_Spec):
    """``{polygon: [[x, y], ...]}``: a simple polygon in 2D (at least 3 vertices, no crossing)."""

    polygon: Annotated[list[list[float]], AfterValidator(_simple_polygon)] = Field(
        description="Vertices [x, y] in order (either orientation); at least 3, edges must not "
        "cross. A closing vertex equal to the first is accepted and dropped."
    )

    @property
    def dim(self) -> int:
        """Dimension of the shape (always 2)."""
        return 2

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners of the smallest axis-aligned box around the shape."""
        pts = np.asarray(self.polygon, dtype=float)
        return pts.min(axis=0), pts.max(axis=0)

    def to_shape(self) -> Polygon:
        """The planner's geometric polygon."""
        return Polygon(np.asarray(self.polygon, dtype=float))


def _shape_kind(value: Any) -> str | None:
    if isinstance(value, dict):
        return str(next(iter(value))) if len(value) == 1 else None
    for kind, cls in (("box", BoxSpec), ("ball", BallSpec), ("polygon", PolygonSpec)):
        if isinstance(value, cls):
            return kind
    return None


def _one_shape_key(value: Any) -> Any:
    """Give a clear error for a shape mapping without exactly one known key."""
    if isinstance(value, BoxSpec | BallSpec | PolygonSpec):
        return value
    kinds = ", ".join(SHAPE_KINDS)
    if not isinstance(value, dict):
        raise PydanticCustomError(
            "shape_type", "a shape must be a mapping with one key: {kinds}", {"kinds": kinds}
        )
    if not value:
        raise PydanticCustomError(
            "shape_keys", "empty shape: give exactly one of {kinds}", {"kinds": kinds}
        )
    if len(value) > 1:
        keys = ", ".join(str(k) for k in value)
        raise PydanticCustomError(
            "shape_keys",
            "a shape has exactly one key ({kinds}), got {n}: {keys}",
            {"kinds": kinds, "n": len(value), "keys": keys},
        )
    key = next(iter(value))
    if key not in SHAPE_KINDS:
        raise PydanticCustomError(
            "shape_keys", "unknown shape '{key}': use one of {kinds}", {"key": key, "kinds": kinds}
        )
    return value


ShapeSpec = Annotated[
    Annotated[BoxSpec, Tag("box")]
    | Annotated[BallSpec, Tag("ball")]
    | Annotated[PolygonSpec, Tag("polygon")],
    Discriminator(_shape_kind),
    BeforeValidator(_one_shape_key),
]
"""A shape mapping with a single key: ``box``, ``ball`` or ``polygon``."""


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


class RandomObstaclesSpec(_Spec):
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
        _check_dim(size, "size")
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
                {"axis": axis, "interval": _fmt(interval)},
            )
    return bounds


class WorldSpec(_Spec):
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
                span = " x ".join(_fmt(pair) for pair in zip(lo, hi, strict=True))
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
    return "[" + ", ".join(_fmt(row) for row in bounds) + "]"
