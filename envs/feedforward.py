"""The guide feed-forward of ``EnvOptions.guide_feedforward``: a command toward the guide's
carrot that the policy's action corrects.

The carrot is the centre of the r-ball ``AHEAD`` balls past the robot's progress index on the
current leg (the leg's last ball at most). For robots commanded by a world-frame velocity or
acceleration (point, quadrotor) the env adds ``gain`` times the unit vector toward it to the
policy's action; for robots driven by (forward, turn) actions (unicycle, racecar) it adds
``gain`` times a turn command toward it (proportional to the heading error, full at 90 degrees
or more) to the turn component. Sums are clipped to ``[-1, 1]``. Following the guide is then
what a zero action does; the policy learns the correction around boxes and into the goal
(residual policy learning, Silver et al. 2018; Johannink et al. 2019), instead of first having
to discover motion at all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from envs.robots.base import wrap_angle

AHEAD = 2
"""Balls past the progress index that the carrot sits (the ``follower`` of the tests)."""

WORLD_FRAME_ROBOTS = frozenset({"point", "quadrotor"})
"""Robots whose action is a world-frame command, one component per workspace axis."""


def carrot_direction(
    centres: np.ndarray, index: int, x: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Unit vector from ``x`` to the carrot of progress index ``index`` (-1: none reached);
    zeros at the carrot."""
    target = centres[min(max(index, -1) + AHEAD, len(centres) - 1)]
    offset = target - np.asarray(x, dtype=float)
    norm = float(np.linalg.norm(offset))
    return offset / norm if norm > 1e-9 else np.zeros_like(offset)


def with_feedforward(action: np.ndarray, gain: float, direction: np.ndarray) -> np.ndarray:
    """``action`` plus ``gain`` times ``direction``, clipped to ``[-1, 1]``."""
    return np.clip(np.asarray(action, dtype=float) + gain * direction, -1.0, 1.0)


def steering_toward(heading: float, direction: np.ndarray) -> float:
    """Turn command in ``[-1, 1]`` from ``heading`` toward the planar ``direction``: the heading
    error over 90 degrees, clipped; 0 for a zero direction."""
    if not np.any(direction[:2]):
        return 0.0
    error = wrap_angle(math.atan2(float(direction[1]), float(direction[0])) - heading)
    return max(-1.0, min(1.0, error / (math.pi / 2)))
