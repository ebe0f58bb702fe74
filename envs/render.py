"""RGB pictures of a navigation episode (matplotlib Agg, no display, no pyplot state).

A 2D world is drawn from above; a 3D world as two panels, from above (x-y) and from the side
(x-z), every shape projected. Obstacles are grey, labelled regions green, the guide paths blue
with their r-balls (those already reached filled), the trail red and the robot black (with a
heading tick for robots steered by heading).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from envs.observation import HEADING_FEATURES
from planner.plot import shape_patch

if TYPE_CHECKING:
    from envs.nav_env import NavEnv

OBSTACLE = "#555555"
REGION = "#7fbf7f"
GUIDE = "#1f5fbf"
BALL = "#c8a000"
TRAIL = "#d0301f"
SIZE_PX = 480


def _panel(ax: Any, env: NavEnv, axes: tuple[int, int]) -> None:
    i, j = axes
    world = env.world
    ax.set_xlim(*world.bounds[i])
    ax.set_ylim(*world.bounds[j])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("xyz"[i], fontsize=8)
    ax.set_ylabel("xyz"[j], fontsize=8)
    for shape in world.obstacles:
        ax.add_patch(shape_patch(shape, OBSTACLE, 0.9, axes))
    for name, shape in world.regions.items():
        ax.add_patch(shape_patch(shape, REGION, 0.5, axes))
        lo, hi = shape.bounding_box()
        ax.annotate(name, ((lo[i] + hi[i]) / 2, (lo[j] + hi[j]) / 2), ha="center", fontsize=8)
    reached = env.progress_index
    for leg in env.legs:
        path = np.asarray(leg.subtask.path)
        ax.plot(path[:, i], path[:, j], "-", color=GUIDE, lw=1.2)
        for k, c in enumerate(leg.guide.centers):
            done = leg.offset + k <= reached
            ax.add_patch(
                Circle(
                    (c[i], c[j]),
                    leg.guide.r,
                    fill=done,
                    color=BALL,
                    alpha=0.35 if done else 0.7,
                    lw=0.5,
                )
            )
    if env.trail:
        trail = np.asarray(env.trail)
        ax.plot(trail[:, i], trail[:, j], "-", color=TRAIL, lw=1.2)
    x = env.robot.position()
    size = max(env.robot.radius, world.diagonal / 200.0)
    ax.add_patch(Circle((x[i], x[j]), size, color="black", zorder=5))
    feats = HEADING_FEATURES.get(env.robot.name)
    if feats is not None and axes == (0, 1):
        obs = env.robot.observation()
        c, s = float(obs[feats[0]]), float(obs[feats[1]])
        ax.plot([x[0], x[0] + 3 * size * c], [x[1], x[1] + 3 * size * s], "-", color="black")


def render_frame(env: NavEnv) -> np.ndarray:
    """The current frame of ``env`` as a ``(H, W, 3)`` uint8 array."""
    views = [(0, 1)] if env.world.dim == 2 else [(0, 1), (0, 2)]
    dpi = 80
    figure = Figure(figsize=(SIZE_PX / dpi * len(views), SIZE_PX / dpi), dpi=dpi)
    canvas = FigureCanvasAgg(figure)
    for k, axes in enumerate(views):
        _panel(figure.add_subplot(1, len(views), k + 1), env, axes)
    figure.suptitle(
        f"{env.mode.name}  step {env.steps}  ball {env.progress_index + 1}/{env.num_balls}",
        fontsize=9,
    )
    figure.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
