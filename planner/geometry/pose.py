"""A robot pose in the workspace: where it stands and which way it faces; headings of paths.

One type for every layer: the Dubins paths and drivable guides of the planner, the real starts
and hand-over poses of the envs, the poses mission rollouts record. A heading is a yaw in the
x-y plane (a 3D robot's height does not turn it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pose:
    """A workspace point ``position`` (2D or 3D) and a yaw ``heading`` (radians,
    counter-clockwise from the x axis)."""

    position: np.ndarray
    heading: float


def yaw(v: np.ndarray) -> float:
    """The heading of the direction ``v``."""
    return math.atan2(float(v[1]), float(v[0]))


def heading_along(path: np.ndarray) -> float:
    """Yaw from ``path[0]`` to its first point apart from it (0 for a single point)."""
    for p in path[1:]:
        d = p - path[0]
        if float(np.hypot(d[0], d[1])) > 1e-9:
            return math.atan2(float(d[1]), float(d[0]))
    return 0.0


def final_heading(path: np.ndarray) -> float:
    """Yaw of the last segment of ``path`` that is not degenerate (0 when none)."""
    for a, b in zip(path[-2::-1], path[:0:-1], strict=True):
        if float(np.hypot(*(b - a)[:2])) > 1e-9:
            return yaw(b - a)
    return 0.0
