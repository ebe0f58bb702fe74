"""Pictures of a world and a mission plan (matplotlib, imported lazily by callers), and the one
drawing of a workspace shape that every picture (``envs.render``, ``workers.bundle``) uses.

Importing this module loads matplotlib's patches but neither pyplot nor a backend: an env that
renders frames must not switch the backend of the process it runs in. :func:`plot_plan` selects
the file backend (Agg) when it draws.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.patches import Circle, Rectangle
from matplotlib.patches import Polygon as PolygonPatch

from planner.geometry.shapes import Ball, Box, Polygon, Shape
from planner.geometry.world import World
from planner.guidance import Guide

if TYPE_CHECKING:
    from planner.plan import MissionPlan

OBSTACLE_COLOUR = "#555555"
REGION_COLOUR = "#7fbf7f"
PREFIX_COLOUR = "#1f5fbf"
SUFFIX_COLOUR = "#d0501f"
BALL_COLOUR = "#c8a000"


def plot_plan(
    world: World,
    plan: MissionPlan,
    out: Path,
    title: str = "",
    guides: Sequence[Guide] | None = None,
) -> None:
    """Draw obstacles, labelled regions, prefix and suffix, and each sub-task's r-balls: those of
    ``guides`` (one per sub-task, what its agent trains on) or else the plan's own."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure(figsize=(7, 7) if world.dim == 2 else (8, 7))
    if guides is None:
        guides = [Guide.from_path(sub.path, plan.r_ball) for sub in plan.subtasks]
    if world.dim == 2:
        _plot_2d(figure.add_subplot(), world, plan, guides)
    else:
        _plot_3d(figure.add_subplot(projection="3d"), world, plan, guides)
    if title:
        figure.suptitle(title)
    figure.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(figure)


def _plot_2d(axes: Any, world: World, plan: MissionPlan, guides: Sequence[Guide]) -> None:
    axes.set_xlim(*world.bounds[0])
    axes.set_ylim(*world.bounds[1])
    axes.set_aspect("equal")
    for shape in world.obstacles:
        axes.add_patch(shape_patch(shape, OBSTACLE_COLOUR, alpha=0.9))
    for label, shape in world.regions.items():
        axes.add_patch(shape_patch(shape, REGION_COLOUR, alpha=0.55))
        centre = np.mean(shape.bounding_box(), axis=0)
        axes.annotate(label, centre, ha="center", va="center", fontsize=9, weight="bold")
    for guide in guides:
        for centre in guide.centers:
            axes.add_patch(
                Circle(tuple(centre), guide.r, fill=False, lw=0.5, color=BALL_COLOUR, alpha=0.7)
            )
    prefix, suffix = plan.lasso.prefix, plan.lasso.suffix
    axes.plot(prefix[:, 0], prefix[:, 1], "-", color=PREFIX_COLOUR, lw=2, label="prefix")
    if len(suffix) > 1:
        axes.plot(suffix[:, 0], suffix[:, 1], "--", color=SUFFIX_COLOUR, lw=2, label="suffix")
    axes.plot(*prefix[0, :2], "o", color="black", label="start")
    axes.legend(loc="upper right", fontsize=8)


def _plot_3d(axes: Any, world: World, plan: MissionPlan, guides: Sequence[Guide]) -> None:
    for dim, setter in enumerate((axes.set_xlim, axes.set_ylim, axes.set_zlim)):
        setter(*world.bounds[dim])
    for shape in world.obstacles:
        lo, hi = shape.bounding_box()
        _wire_box(axes, lo, hi, OBSTACLE_COLOUR)
    for label, shape in world.regions.items():
        lo, hi = shape.bounding_box()
        centre = (lo + hi) / 2
        axes.scatter(*centre, color=REGION_COLOUR, s=120, alpha=0.8)
        axes.text(*centre, label, fontsize=8)
    prefix, suffix = plan.lasso.prefix, plan.lasso.suffix
    axes.plot(
        prefix[:, 0], prefix[:, 1], prefix[:, 2], "-", color=PREFIX_COLOUR, lw=2, label="prefix"
    )
    if len(suffix) > 1:
        axes.plot(
            suffix[:, 0],
            suffix[:, 1],
            suffix[:, 2],
            "--",
            color=SUFFIX_COLOUR,
            lw=2,
            label="suffix",
        )
    for guide in guides:
        centres = guide.centers
        axes.scatter(centres[:, 0], centres[:, 1], centres[:, 2], color=BALL_COLOUR, s=6)
    axes.scatter(*prefix[0], color="black", s=30, label="start")
    axes.legend(loc="upper right", fontsize=8)


def shape_patch(shape: Shape, colour: str, alpha: float, axes: tuple[int, int] = (0, 1)) -> Any:
    """A filled matplotlib patch of ``shape`` projected on the workspace axes ``axes`` (x-y by
    default; a polygon is planar and drawn as it is)."""
    i, j = axes
    if isinstance(shape, Box):
        lo, hi = shape.lo, shape.hi
        return Rectangle(
            (lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], color=colour, alpha=alpha, lw=0
        )
    if isinstance(shape, Ball):
        centre = (shape.center[i], shape.center[j])
        return Circle(centre, shape.radius, color=colour, alpha=alpha, lw=0)
    if isinstance(shape, Polygon):
        return PolygonPatch(shape.vertices, closed=True, color=colour, alpha=alpha, lw=0)
    raise TypeError(f"cannot draw shape {shape!r}")


def _wire_box(axes: Any, lo: np.ndarray, hi: np.ndarray, colour: str) -> None:
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                axes.plot(*zip(corners[i], corners[j], strict=True), color=colour, lw=0.6)
