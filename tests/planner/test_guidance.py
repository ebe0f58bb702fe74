"""r-ball guide maths and progress tracking (the paper's reward over them is tested in
``tests/envs/test_rewards.py``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner.guidance import Guide, ProgressTracker


def brute_index(guide: Guide, points: np.ndarray) -> np.ndarray:
    inside = ((points[:, None, :] - guide.centers[None]) ** 2).sum(-1) <= guide.r**2
    d = np.where(inside, guide.dist_to_go[None], np.inf)
    best = d.min(axis=1)
    # highest index among the balls realising the minimum
    last = guide.num_balls - 1 - np.argmax((d == best[:, None])[:, ::-1], axis=1)
    return np.where(inside.any(axis=1), last, -1)


def test_resampling_spacing_and_dist_to_go() -> None:
    path = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5]])
    guide = Guide.from_path(path, r=0.1)
    gaps = np.linalg.norm(np.diff(guide.centers, axis=0), axis=1)
    assert np.all(gaps <= 0.2 + 1e-12)
    # every waypoint is a centre, the first and last ones in place
    for w in path:
        assert np.min(np.linalg.norm(guide.centers - w, axis=1)) < 1e-12
    np.testing.assert_allclose(guide.centers[0], path[0])
    np.testing.assert_allclose(guide.centers[-1], path[-1])
    assert guide.dist_to_go[-1] == 0.0
    assert guide.dist_to_go[0] == pytest.approx(1.5)
    assert guide.length == pytest.approx(1.5)
    assert np.all(np.diff(guide.dist_to_go) < 0)
    np.testing.assert_allclose(-np.diff(guide.dist_to_go), gaps)


def test_custom_spacing_and_duplicates() -> None:
    path = np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 4.0]])
    guide = Guide.from_path(path, r=0.5, spacing=0.25)
    assert guide.num_balls == 21  # 5 / 0.25 gaps
    single = Guide.from_path(np.array([[1.0, 2.0]]), r=0.3)
    assert single.num_balls == 1
    assert single.distance_to_go(np.array([[1.1, 2.0], [2.0, 2.0]])).tolist() == [0.0, np.inf]
    with pytest.raises(ValueError):
        Guide.from_path(np.zeros((0, 2)), r=0.1)
    with pytest.raises(ValueError):
        Guide.from_path(path, r=0.0)


def test_distance_to_go_is_min_over_containing_balls() -> None:
    guide = Guide.from_path(np.array([[0.0, 0.0], [1.0, 0.0]]), r=0.125)
    pts = np.array([[0.0, 0.0], [0.5, 0.05], [1.0, 0.0], [0.5, 0.5], [0.125, 0.0]])
    d = guide.distance_to_go(pts)
    assert d[0] == pytest.approx(1.0)
    assert d[1] == pytest.approx(0.5)
    assert d[2] == 0.0
    assert d[3] == np.inf
    # on the boundary between ball 0 and ball 1 the lesser distance-to-go wins
    assert d[4] == pytest.approx(0.75)
    assert guide.ball_index(pts).tolist() == [0, 2, 4, -1, 1]


@pytest.mark.parametrize("dim", [2, 3])
def test_vectorised_and_scalar_paths_match_brute_force(dim: int) -> None:
    rng = np.random.default_rng(dim)
    # a folding random walk: balls of distant path parts overlap
    path = np.cumsum(rng.normal(size=(60, dim)) * 0.4, axis=0)
    guide = Guide.from_path(path, r=0.3)
    pts = guide.centers[rng.integers(0, guide.num_balls, 2000)] + rng.normal(size=(2000, dim)) * 0.3
    expected = brute_index(guide, pts)
    assert (expected >= 0).any() and (expected < 0).any()
    np.testing.assert_array_equal(guide.ball_index(pts), expected)
    assert [guide.locate(p) for p in pts] == expected.tolist()
    assert [guide.locate(tuple(p)) for p in pts[:50].tolist()] == expected[:50].tolist()
    d = guide.distance_to_go(pts)
    np.testing.assert_array_equal(np.isinf(d), expected < 0)
    np.testing.assert_allclose(d[expected >= 0], guide.dist_to_go[expected[expected >= 0]])


def test_batch_tracker_matches_scalar_path_and_reset() -> None:
    rng = np.random.default_rng(7)
    path = np.cumsum(rng.normal(size=(20, 2)), axis=0)
    guide = Guide.from_path(path, r=0.4)
    batch = ProgressTracker(guide, num_envs=8)
    scalar = ProgressTracker(guide, num_envs=8)
    batch.reset()
    scalar.reset()
    along = np.minimum(np.arange(200)[:, None] // 2 + np.arange(8)[None], guide.num_balls - 1)
    walk = guide.centers[along] + rng.normal(size=(200, 8, 2)) * 0.3
    improvements = 0
    for pts in walk:
        step = batch.update(pts)
        for e in range(8):
            imp, idx, d = scalar.update_one(e, pts[e])
            assert imp == bool(step.improved[e])
            assert idx == int(step.index[e])
            assert d == step.d[e]
        improvements += int(step.improved.sum())
    assert improvements > 8
    np.testing.assert_array_equal(batch.d_min, scalar.d_min)
    batch.reset(np.array([True] + [False] * 7), start_index=3)
    assert batch.index[0] == 3 and batch.d_min[0] == guide.dist_to_go[3]
    batch.reset([1, 2])
    assert batch.index[1] == -1 and batch.d_min[2] == np.inf
    with pytest.raises(ValueError):
        batch.reset(0, start_index=guide.num_balls)


def _hairpin() -> Guide:
    """Out along y = 0 and back along y = 0.6: the return balls overlap the outward ones."""
    return Guide.from_path(np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 0.6], [0.0, 0.6]]), r=0.5)


def test_a_progress_window_stops_a_hairpin_from_being_cut_short() -> None:
    guide = _hairpin()
    start = [0.1, 0.2]
    free, windowed = ProgressTracker(guide), ProgressTracker(guide, window=2)
    assert free.locate(start) == guide.num_balls - 1  # the paper's D: the end of the hairpin
    assert windowed.locate(start) == 0
    improved, index, _ = free.update_one(0, start)
    assert improved and index == guide.num_balls - 1
    improved, index, _ = windowed.update_one(0, start)
    assert improved and index == 0
    # Driving the guide, the windowed tracker passes every ball in order.
    dense = np.vstack([np.linspace(a, b, 30) for a, b in itertools.pairwise(guide.centers)])
    seen = [windowed.update_one(0, p)[1] for p in dense]
    assert sorted(set(seen)) == list(range(guide.num_balls))
    assert seen == sorted(seen)


def test_the_batch_path_and_reset_respect_the_window() -> None:
    guide = _hairpin()
    tracker = ProgressTracker(guide, num_envs=2, window=2)
    tracker.reset(points=np.array([[0.1, 0.1], [1.2, 0.1]]))
    assert tracker.index.tolist() == [0, 1]  # reset by points looks only into the first window
    step = tracker.update(np.array([[0.1, 0.5], [2.9, 0.1]]))
    assert step.index.tolist() == [0, 3]
    assert ProgressTracker(guide).update(np.array([[0.1, 0.5]])).index.tolist() == [
        guide.num_balls - 1
    ]
    with pytest.raises(ValueError, match="window"):
        ProgressTracker(guide, window=0)
