"""Dubins paths: every word lands on the goal pose, the shortest is the expected one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.geometry.dubins import WORDS, dubins_words
from planner.geometry.pose import Pose


def _angle_gap(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


def test_every_word_ends_at_the_goal_pose_and_samples_densely() -> None:
    rng = np.random.default_rng(0)
    seen: set[str] = set()
    for _ in range(2000):
        start = Pose(rng.uniform(-5, 5, 2), rng.uniform(-4, 4))
        goal = Pose(rng.uniform(-5, 5, 2), rng.uniform(-4, 4))
        rho = float(rng.uniform(0.2, 2.0))
        words = dubins_words(start, goal, rho)
        assert 2 <= len(words) <= 6
        assert [w.length for w in words] == sorted(w.length for w in words)
        assert words[0].length >= math.dist(goal.position, start.position) - 1e-9
        for path in words:
            seen.add(path.word)
            end = path.end()
            assert math.dist(end.position, goal.position) < 1e-6
            assert _angle_gap(end.heading, goal.heading) < 1e-6
            points, headings = path.sample(0.05)
            np.testing.assert_allclose(points[0], start.position, atol=1e-9)
            np.testing.assert_allclose(points[-1], goal.position, atol=1e-6)
            steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
            assert steps.max() <= 0.05 + 1e-9
            # Curvature bound: the heading turns at most (arc between samples) / rho.
            arc = path.length / (len(points) - 1)
            assert np.all(np.abs(np.diff(headings)) <= arc / rho + 1e-9)
    assert seen == set(WORDS)


def test_straight_ahead_is_a_line_and_turning_back_is_a_half_circle() -> None:
    ahead = dubins_words(Pose(np.array([0, 0]), 0), Pose(np.array([3, 0]), 0), 1.0)[0]
    assert ahead.length == pytest.approx(3.0)
    back = dubins_words(Pose(np.array([0, 0]), 0), Pose(np.array([0, 2]), math.pi), 1.0)[0]
    assert back.word[0] == "L" and back.length == pytest.approx(math.pi)
    same = dubins_words(Pose(np.array([1, 1]), 0.3), Pose(np.array([1, 1]), 0.3), 0.5)[0]
    assert same.length == pytest.approx(0.0, abs=1e-9)


def test_a_bad_radius_or_step_is_refused() -> None:
    with pytest.raises(ValueError, match="turning radius"):
        dubins_words(Pose(np.array([0, 0]), 0), Pose(np.array([1, 0]), 0), 0.0)
    path = dubins_words(Pose(np.array([0, 0]), 0), Pose(np.array([1, 0]), 0), 1.0)[0]
    with pytest.raises(ValueError, match="step"):
        path.sample(0.0)
