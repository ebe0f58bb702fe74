"""Polylines: waypoints ``(n, d)`` joined by straight segments."""

from __future__ import annotations

import numpy as np


def path_length(points: np.ndarray) -> float:
    """Euclidean length of a polyline ``(n, d)`` (0 for fewer than two points)."""
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
