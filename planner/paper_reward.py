"""The paper's reward over the r-ball progress of ``planner.guidance`` (Cai et al., RA-L 2023).

``R-`` in an obstacle (first priority), ``R++`` at the destination (``D = 0``), ``R+`` on a new
minimum of ``D`` and 0 otherwise. The envs layer's reward modes (``envs.rewards``) build on the
same rule; this is its reference form, vectorised and scalar.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RewardConstants:
    """The paper's reward values: ``R-`` (crash), ``R++`` (goal) and ``R+`` (progress)."""

    crash: float = -100.0
    goal: float = 200.0
    progress: float = 5.0


def paper_reward(
    in_obstacle: np.ndarray,
    at_goal: np.ndarray,
    improved: np.ndarray,
    constants: RewardConstants | None = None,
) -> np.ndarray:
    """Vectorised reward: ``R-`` if in an obstacle, else ``R++`` at the goal, else ``R+`` on
    progress, else 0. The arguments are boolean arrays of one shape (a batch of envs)."""
    c = constants if constants is not None else RewardConstants()
    return np.where(
        np.asarray(in_obstacle, dtype=bool),
        c.crash,
        np.where(
            np.asarray(at_goal, dtype=bool),
            c.goal,
            np.where(np.asarray(improved, dtype=bool), c.progress, 0.0),
        ),
    ).astype(np.float64)


def paper_reward_one(
    in_obstacle: bool, at_goal: bool, improved: bool, constants: RewardConstants | None = None
) -> float:
    """Scalar twin of :func:`paper_reward` for a single env (no numpy overhead)."""
    c = constants if constants is not None else RewardConstants()
    if in_obstacle:
        return c.crash
    if at_goal:
        return c.goal
    if improved:
        return c.progress
    return 0.0
