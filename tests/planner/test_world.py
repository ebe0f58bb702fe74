"""World: labels, collisions with clearance, sampling, label changes and realisability."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import WorldError
from planner.geometry.shapes import Ball, Box, Polygon, Shape
from planner.geometry.world import World


def mixed_world() -> World:
    """2D world with every obstacle kind and overlapping, nested and disjoint regions."""
    obstacles: list[Shape] = [
        Box([1.0, 1.0], [2.0, 3.0]),
        Box([-4.0, -1.0], [-3.0, 4.0]),
        Ball([4.0, 4.0], 0.5),
        Polygon([[0.0, -4.0], [2.0, -4.0], [1.0, -2.5]]),
    ]
    regions: dict[str, Shape] = {
        "g1": Ball([3.0, -3.0], 1.0),
        "g2": Box([2.5, -3.5], [4.5, -1.5]),  # overlaps g1
        "g3": Box([-2.0, 2.0], [-1.0, 3.0]),  # disjoint from g1 and g2
        "inner": Ball([-1.5, 2.5], 0.2),  # inside g3
        "trapped": Ball([1.5, 2.0], 0.3),  # inside an obstacle
        "tri": Polygon([[-4.5, -4.5], [-2.0, -4.5], [-4.5, -2.0]]),
    }
    return World([[-5.0, 5.0], [-5.0, 5.0]], obstacles, regions)


def test_labels_and_label_matrix() -> None:
    w = mixed_world()
    assert w.dim == 2 and w.diagonal == pytest.approx(np.hypot(10, 10))
    assert w.region_names == ("g1", "g2", "g3", "inner", "trapped", "tri")
    assert w.labels(np.array([3.0, -3.0])) == {"g1", "g2"}
    assert w.labels([-1.5, 2.5]) == {"g3", "inner"}
    assert w.labels([1.5, 2.0]) == {"trapped", World.OBSTACLE}
    assert w.labels([0.0, 0.0]) == frozenset()
    assert w.labels([1.0, -3.0]) == {World.OBSTACLE}
    pts = np.random.default_rng(0).uniform(-5, 5, (500, 2))
    matrix = w.label_matrix(pts)
    assert matrix.shape == (500, 6)
    for p, row in zip(pts, matrix, strict=True):
        names = {n for n, inside in zip(w.region_names, row, strict=True) if inside}
        assert w.labels(p) - {World.OBSTACLE} == names


def test_in_collision_matches_per_obstacle_checks() -> None:
    w = mixed_world()
    pts = np.random.default_rng(1).uniform(-5.5, 5.5, (3000, 2))
    for clearance in (0.0, 0.3):
        expected = np.zeros(len(pts), dtype=bool)
        for shape in w.obstacles:
            expected |= shape.contains(pts, clearance)
        expected |= np.any((pts < -5.0 + clearance) | (pts > 5.0 - clearance), axis=1)
        np.testing.assert_array_equal(w.in_collision(pts, clearance), expected)


def test_obstacle_distance_is_the_clearance_at_which_a_point_starts_colliding() -> None:
    w = mixed_world()
    pts = np.random.default_rng(2).uniform(-5.5, 5.5, (3000, 2))
    d = w.obstacle_distance(pts)
    assert np.all(d >= 0.0)
    np.testing.assert_array_equal(d == 0.0, w.in_collision(pts, 0.0))
    free = d > 1e-6
    assert not w.in_collision(pts[free], 0.0).any()
    for point, distance in zip(pts[free], d[free], strict=True):
        assert not w.in_collision(point[None, :], distance - 1e-6)[0]
        assert w.in_collision(point[None, :], distance + 1e-6)[0]


def test_clearance_inflates_obstacles_and_shrinks_bounds() -> None:
    w = mixed_world()
    near_box = np.array([[2.15, 2.0]])  # 0.15 right of the first box
    assert not w.in_collision(near_box, 0.1)[0]
    assert w.in_collision(near_box, 0.2)[0]
    near_wall = np.array([[-4.85, -4.0]])
    assert not w.in_collision(near_wall, 0.1)[0]
    assert w.in_collision(near_wall, 0.2)[0]
    assert w.in_collision([[6.0, 0.0]])[0]
    assert w.segment_free([0.0, 0.0], [0.0, 4.0], 0.5)
    assert not w.segment_free([0.0, 0.0], [0.0, 4.9], 0.2)  # ends too close to the wall
    assert not w.segment_free([2.15, 0.0], [2.15, 4.0], 0.2)
    assert w.segment_free([2.15, 0.0], [2.15, 4.0], 0.1)


@pytest.mark.parametrize("dim", [2, 3])
def test_segments_free_never_misses_a_sampled_collision(dim: int) -> None:
    rng = np.random.default_rng(dim)
    obstacles: list[Shape] = []
    for _ in range(12):
        c = rng.uniform(-4, 4, dim)
        obstacles.append(Box(c - 0.5, c + rng.uniform(-0.3, 0.8, dim) + 0.5))
        obstacles.append(Ball(rng.uniform(-4, 4, dim), float(rng.uniform(0.2, 0.8))))
    if dim == 2:
        obstacles.append(Polygon([[-1.0, -1.0], [1.0, -1.0], [0.0, 1.5]]))
    w = World([[-5.0, 5.0]] * dim, obstacles, {})
    a = w.sample_free(rng, 400, 0.0)
    b = a + rng.normal(scale=1.0, size=a.shape)
    t = np.linspace(0.0, 1.0, 1001)
    for clearance in (0.0, 0.25):
        free = w.segments_free(a, b, clearance)
        per_shape = np.ones(len(a), dtype=bool)
        for shape in obstacles:
            per_shape &= ~shape.segments_intersect(a, b, clearance)
        inside = np.all(
            (np.minimum(a, b) >= -5 + clearance) & (np.maximum(a, b) <= 5 - clearance), 1
        )
        np.testing.assert_array_equal(free, per_shape & inside)
        pts = (a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]).reshape(-1, dim)
        sampled = w.in_collision(pts, clearance).reshape(len(a), -1).any(axis=1)
        assert not np.any(free & sampled)
        assert 0.2 < float(free.mean()) < 0.9


def test_sampling_is_free_seeded_and_in_the_region() -> None:
    w = mixed_world()
    pts = w.sample_free(np.random.default_rng(3), 1000, 0.3)
    assert pts.shape == (1000, 2)
    assert not np.any(w.in_collision(pts, 0.3))
    np.testing.assert_array_equal(pts, w.sample_free(np.random.default_rng(3), 1000, 0.3))
    g1 = w.sample_region("g1", np.random.default_rng(4), 200, 0.1)
    assert 0 < len(g1) <= 200
    assert np.all(w.regions["g1"].contains(g1)) and not np.any(w.in_collision(g1, 0.1))
    assert len(w.sample_region("trapped", np.random.default_rng(4), 200)) == 0
    with pytest.raises(WorldError, match="no such region"):
        w.sample_region("nowhere", np.random.default_rng(0), 5)


def test_sample_free_reports_a_full_workspace() -> None:
    w = World([[0.0, 1.0], [0.0, 1.0]], [Box([-1.0, -1.0], [2.0, 2.0])], {})
    with pytest.raises(WorldError, match="cover the workspace"):
        w.sample_free(np.random.default_rng(0), 10)
    with pytest.raises(WorldError, match="no room"):
        World([[0.0, 1.0], [0.0, 1.0]], [], {}).sample_free(np.random.default_rng(0), 1, 0.6)


def dense_label_changes(w: World, a: np.ndarray, b: np.ndarray, n: int = 20001) -> int:
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + t * (b - a)
    lab = np.c_[w.label_matrix(pts), w.in_collision(pts)]
    return int(np.any(lab[1:] != lab[:-1], axis=1).sum())


def test_segment_label_changes() -> None:
    w = mixed_world()
    assert w.segment_label_changes([0.0, -3.0], [0.0, -3.0]) == 0
    assert w.segment_label_changes([0.0, 0.0], [0.5, 0.5]) == 0
    assert w.segment_label_changes([3.0, -3.0], [3.0, 0.0]) == 2  # {g1,g2} -> {g2} -> {}
    assert w.segment_label_changes([-2.9, 2.5], [0.0, 2.5]) == 4  # {} g3 {g3,inner} g3 {}
    assert w.segment_label_changes([-3.0, 2.5], [0.0, 2.5]) == 5  # starts on an obstacle face
    assert w.segment_label_changes([1.5, 0.0], [1.5, 2.0]) == 2  # into the obstacle, trapped
    # grazing the bottom of ball g1 at one point: two changes that sampling would miss
    assert w.segment_label_changes([2.2, -4.0], [3.8, -4.0]) == 2
    assert w.segment_label_changes([2.0, -2.0], [4.0, -2.0]) == 3  # {} g2 {g1,g2} g2
    rng = np.random.default_rng(11)
    a = rng.uniform(-5, 5, (150, 2))
    b = rng.uniform(-5, 5, (150, 2))
    exact = w.segments_label_changes(a, b)
    assert exact.shape == (150,)
    for i in range(len(a)):
        assert exact[i] == dense_label_changes(w, a[i], b[i])
    assert exact.max() >= 4


def test_label_changes_in_3d() -> None:
    w = World(
        [[0.0, 4.0]] * 3, [Box([1.0, 1.0, 1.0], [2.0, 2.0, 2.0])], {"g": Ball([3.0, 3.0, 3.0], 0.5)}
    )
    assert w.segment_label_changes([0.5, 1.5, 1.5], [2.5, 1.5, 1.5]) == 2
    assert w.segment_label_changes([0.5, 0.5, 0.5], [3.0, 3.0, 3.0]) == 3
    assert w.labels([3.0, 3.0, 3.2]) == {"g"}


def test_realisable() -> None:
    w = mixed_world()
    yes = [
        ({"g1"}, set()),
        ({"g1", "g2"}, set()),
        ({"g3", "inner"}, set()),
        (set(), set()),
        ({"g3"}, {"inner"}),
        ({"tri"}, set()),
        ({"g1"}, {"g2", "g3"}),
        (set(), set(w.region_names)),
    ]
    no = [
        ({"obstacle"}, set()),
        ({"g1", "g3"}, set()),
        ({"trapped"}, set()),
        ({"inner"}, {"g3"}),
        ({"g1"}, {"g1"}),
        ({"unknown"}, set()),
        ({"tri", "g1"}, set()),
        ({"g2", "inner"}, set()),
    ]
    for pos, neg in yes:
        assert w.realisable(frozenset(pos), frozenset(neg)), (pos, neg)
    for pos, neg in no:
        assert not w.realisable(frozenset(pos), frozenset(neg)), (pos, neg)
    assert w.realisable(frozenset({"g3"}), frozenset({World.OBSTACLE}))
    # with a clearance of 3.1 the robot's centre stays within [-1.9, 1.9]^2, away from g1
    assert w.realisable(frozenset({"g1"}), frozenset(), clearance=0.5)
    assert not w.realisable(frozenset({"g1"}), frozenset(), clearance=3.1)


def test_realisable_respects_obstacles_covering_an_overlap() -> None:
    regions: dict[str, Shape] = {"a": Box([0.0, 0.0], [2.0, 2.0]), "b": Box([1.0, 1.0], [3.0, 3.0])}
    blocked = World([[0.0, 4.0], [0.0, 4.0]], [Box([0.9, 0.9], [2.1, 2.1])], regions)
    assert not blocked.realisable(frozenset({"a", "b"}), frozenset())
    assert blocked.realisable(frozenset({"a"}), frozenset({"b"}))
    free = World([[0.0, 4.0], [0.0, 4.0]], [], regions)
    assert free.realisable(frozenset({"a", "b"}), frozenset())


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"bounds": [[0, 1]]}, "bounds"),
        ({"bounds": [[0, 1], [1, 0]]}, "bounds"),
        ({"obstacles": [Box([0, 0, 0], [1, 1, 1])]}, "obstacles[0]"),
        ({"obstacles": [Box([0, 0], [1, 1]), Ball([20, 20], 1)]}, "obstacles[1]"),
        ({"regions": {"obstacle": Ball([0, 0], 1)}}, "regions.obstacle"),
        ({"regions": {"G1": Ball([0, 0], 1)}}, "regions.G1"),
        ({"regions": {"g1": Ball([0, 0, 0], 1)}}, "regions.g1"),
    ],
)
def test_malformed_worlds_name_the_field(kwargs: dict[str, object], field: str) -> None:
    args: dict[str, object] = {"bounds": [[-5, 5], [-5, 5]], "obstacles": [], "regions": {}}
    args.update(kwargs)
    with pytest.raises(WorldError) as info:
        World(**args)  # type: ignore[arg-type]
    assert info.value.field == field
