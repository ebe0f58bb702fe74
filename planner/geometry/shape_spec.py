"""The shape mappings of a ``world:`` section (``{box: ...}``, ``{ball: ...}``,
``{polygon: ...}``), validated with pydantic, and the located problems every section's model
validators raise."""

from __future__ import annotations

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
    model_validator,
)
from pydantic_core import PydanticCustomError

from planner.geometry.shapes import Ball, Box, Polygon

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


def fmt_values(values: Sequence[float] | np.ndarray) -> str:
    """``[1, 2.5]``: numbers as a message shows them."""
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def check_dim(values: list[float], what: str) -> list[float]:
    """``values`` if it is a 2D or 3D point or size, else a located error naming ``what``."""
    if len(values) not in (2, 3):
        raise PydanticCustomError(
            "dimension",
            "{what} needs 2 (2D) or 3 (3D) numbers, got {n}",
            {"what": what, "n": len(values)},
        )
    return values


class SectionModel(BaseModel):
    """A part of a mission document: unknown keys and non-finite numbers are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class BoxBody(SectionModel):
    """An axis-aligned box given by two opposite corners."""

    min: list[float] = Field(description="Lower corner: one coordinate per axis (2 or 3).")
    max: list[float] = Field(description="Upper corner: one coordinate per axis, each > min.")

    @model_validator(mode="after")
    def _corners(self) -> BoxBody:
        check_dim(self.min, "min")
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


class BoxSpec(SectionModel):
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


class BallBody(SectionModel):
    """A disc (2D) or a sphere (3D)."""

    center: Annotated[list[float], AfterValidator(lambda v: check_dim(v, "center"))] = Field(
        description="Centre: one coordinate per axis (2 or 3)."
    )
    radius: float = Field(gt=0, description="Radius in workspace units; must be > 0.")


class BallSpec(SectionModel):
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


class PolygonSpec(SectionModel):
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
