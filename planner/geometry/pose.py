"""A robot pose in the workspace: where it stands and which way it faces.

One type for every layer: the Dubins paths and drivable guides of the planner, the real starts
and hand-over poses of the envs, the poses mission rollouts record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pose:
    """A workspace point ``position`` (2D or 3D) and a yaw ``heading`` (radians,
    counter-clockwise from the x axis)."""

    position: np.ndarray
    heading: float
