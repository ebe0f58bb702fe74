"""Shapes against brute force: dense sampling of segments and independent distance formulas."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from planner.geometry.shapes import Ball, Box, Polygon, Shape, segment_box_sqdist

RESOLUTION = 2001  # points sampled along every segment by the brute-force checks


def brute_distance(shape: Shape, p: np.ndarray) -> np.ndarray:
    """Distance to the shape computed without the code under test (polygon: winding angles)."""
    if isinstance(shape, Box):
        return np.linalg.norm(p - np.clip(p, shape.lo, shape.hi), axis=-1)
    if isinstance(shape, Ball):
        return np.maximum(np.linalg.norm(p - shape.center, axis=-1) - shape.radius, 0.0)
    v0 = shape.vertices
    v1 = np.roll(v0, -1, axis=0)
    flat = p.reshape(-1, 2)
    d0 = v0[None] - flat[:, None]
    d1 = v1[None] - flat[:, None]
    angles = np.arctan2(d0[..., 0] * d1[..., 1] - d0[..., 1] * d1[..., 0], (d0 * d1).sum(-1))
    inside = np.abs(angles.sum(axis=1)) > math.pi
    e = v1 - v0
    t = np.clip(((flat[:, None] - v0) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
    edge = np.linalg.norm(flat[:, None] - (v0 + t[..., None] * e), axis=-1).min(axis=1)
    return np.where(inside, 0.0, edge).reshape(p.shape[:-1])


def random_shapes(rng: np.random.Generator, dim: int) -> list[Shape]:
    shapes: list[Shape] = []
    for _ in range(4):
        lo = rng.uniform(-2, 1, dim)
        shapes.append(Box(lo, lo + rng.uniform(0.2, 2.0, dim)))
        shapes.append(Ball(rng.uniform(-1, 1, dim), float(rng.uniform(0.2, 1.5))))
    if dim == 2:
        shapes.append(Polygon([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [1.0, 0.7], [0.0, 2.0]]))
        shapes.append(Polygon([[-1.0, -1.0], [1.5, -0.5], [0.2, 1.4]]))
        angles = np.sort(rng.uniform(0, 2 * math.pi, 9))
        radii = rng.uniform(0.5, 1.5, 9)
        shapes.append(Polygon(np.c_[radii * np.cos(angles), radii * np.sin(angles)]))
    return shapes


CASES = [
    (dim, i) for dim in (2, 3) for i in range(len(random_shapes(np.random.default_rng(0), dim)))
]


@pytest.mark.parametrize(("dim", "index"), CASES)
def test_segments_match_dense_sampling(dim: int, index: int) -> None:
    rng = np.random.default_rng(100 + index)
    shape = random_shapes(np.random.default_rng(dim), dim)[index]
    n = 300
    lo, hi = shape.bounding_box()
    a = rng.uniform(lo - 1.0, hi + 1.0, (n, dim))
    b = a + rng.normal(scale=1.0, size=(n, dim))
    t = np.linspace(0.0, 1.0, RESOLUTION)
    pts = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
    sampled = brute_distance(shape, pts).min(axis=1)
    step = np.linalg.norm(b - a, axis=1) / (RESOLUTION - 1)
    for margin in (0.0, 0.1, 0.4):
        hit = shape.segments_intersect(a, b, margin)
        assert np.all(hit[sampled <= margin]), "a colliding segment was reported free"
        clearly_free = sampled > margin + step + 1e-6
        assert not np.any(hit[clearly_free]), "a clearly free segment was reported colliding"
    assert 0.05 < float(np.mean(sampled <= 0.1)) < 0.95  # both outcomes are exercised


@pytest.mark.parametrize("dim", [2, 3])
def test_segment_box_distance_is_exact(dim: int) -> None:
    rng = np.random.default_rng(7)
    lo = rng.uniform(-1, 0, (200, dim))
    hi = lo + rng.uniform(0.1, 1.5, (200, dim))
    a = rng.uniform(-3, 3, (200, dim))
    b = a + rng.normal(size=(200, dim))
    exact = np.sqrt(segment_box_sqdist(a, b, lo, hi))
    t = np.linspace(0.0, 1.0, RESOLUTION)
    pts = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
    sampled = np.linalg.norm(pts - np.clip(pts, lo[:, None], hi[:, None]), axis=-1).min(axis=1)
    step = np.linalg.norm(b - a, axis=1) / (RESOLUTION - 1)
    assert np.all(exact <= sampled + 1e-9)
    assert np.all(exact >= sampled - step)
    degenerate = np.sqrt(segment_box_sqdist(a, a, lo, hi))
    np.testing.assert_allclose(degenerate, np.linalg.norm(a - np.clip(a, lo, hi), axis=1))


@pytest.mark.parametrize(("dim", "index"), CASES)
def test_contains_and_distance_match_brute_force(dim: int, index: int) -> None:
    rng = np.random.default_rng(200 + index)
    shape = random_shapes(np.random.default_rng(dim), dim)[index]
    p = rng.uniform(-3.5, 3.5, (4000, dim))
    expected = brute_distance(shape, p)
    np.testing.assert_allclose(shape.distance(p), expected, atol=1e-9)
    for margin in (0.0, 0.25):
        inside = shape.contains(p, margin)
        settled = np.abs(expected - margin) > 1e-9
        np.testing.assert_array_equal(inside[settled], (expected <= margin)[settled])
    assert shape.contains(p[0]).shape == (1,)


def test_box_margin_rounds_the_corners() -> None:
    box = Box([0.0, 0.0], [1.0, 1.0])
    corner = np.array([[1.08, 1.08]])  # 0.113 from the corner, 0.08 from each face plane
    assert not box.contains(corner, 0.1)[0]
    assert box.contains(corner, 0.12)[0]
    assert not box.segments_intersect([[1.08, 1.5]], [[1.5, 1.08]], 0.1)[0]
    assert box.segments_intersect([[1.0, 1.05]], [[1.05, 1.0]], 0.1)[0]


def test_touching_counts_as_intersecting() -> None:
    box = Box([0.0, 0.0], [1.0, 1.0])
    assert box.segments_intersect([[-1.0, 1.0]], [[2.0, 1.0]])[0]
    assert box.contains([[1.0, 0.5]])[0]
    ball = Ball([0.0, 0.0], 1.0)
    assert ball.segments_intersect([[-1.0, 1.0]], [[1.0, 1.0]])[0]
    square = Polygon([[0, 0], [1, 0], [1, 1], [0, 1]])
    assert square.contains([[1.0, 0.5]])[0]
    assert square.segments_intersect([[2.0, 0.5]], [[1.0, 0.5]])[0]


@pytest.mark.parametrize(("dim", "index"), CASES)
def test_sampling_stays_inside_and_is_seeded(dim: int, index: int) -> None:
    shape = random_shapes(np.random.default_rng(dim), dim)[index]
    pts = shape.sample(np.random.default_rng(5), 500)
    assert pts.shape == (500, dim)
    assert np.all(shape.contains(pts, 1e-12))
    np.testing.assert_array_equal(pts, shape.sample(np.random.default_rng(5), 500))
    lo, hi = shape.bounding_box()
    assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)


@pytest.mark.parametrize(("dim", "index"), CASES)
def test_volume_matches_monte_carlo(dim: int, index: int) -> None:
    shape = random_shapes(np.random.default_rng(dim), dim)[index]
    lo, hi = shape.bounding_box()
    p = np.random.default_rng(9).uniform(lo, hi, (200_000, dim))
    estimate = float(np.prod(hi - lo)) * float(shape.contains(p).mean())
    assert shape.volume == pytest.approx(estimate, rel=0.03)


def test_ball_sampling_is_uniform_in_radius() -> None:
    ball = Ball([1.0, 2.0, 3.0], 2.0)
    r = np.linalg.norm(ball.sample(np.random.default_rng(1), 20_000) - ball.center, axis=1)
    assert float(np.mean(r <= 1.0)) == pytest.approx(1 / 8, abs=0.01)


@pytest.mark.parametrize(("dim", "index"), CASES)
def test_boundary_params_cut_segments_into_constant_pieces(dim: int, index: int) -> None:
    rng = np.random.default_rng(300 + index)
    shape = random_shapes(np.random.default_rng(dim), dim)[index]
    a = rng.uniform(-3, 3, (100, dim))
    b = a + rng.normal(scale=2.0, size=(100, dim))
    knots = shape.boundary_params(a, b)
    t = np.linspace(0.0, 1.0, 501)
    for i in range(len(a)):
        inside = shape.contains(a[i] + t[:, None] * (b[i] - a[i]))
        changes = np.flatnonzero(inside[1:] != inside[:-1])
        cuts = knots[i][np.isfinite(knots[i])]
        for c in changes:
            assert np.any((cuts >= t[c] - 1e-9) & (cuts <= t[c + 1] + 1e-9))


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (lambda: Box([0, 0], [0, 1]), "below max"),
        (lambda: Box([0, 0], [1, 1, 1]), "dimension"),
        (lambda: Box([0, 0, 0, 0], [1, 1, 1, 1]), "length 2 or 3"),
        (lambda: Box([0, math.nan], [1, 1]), "finite"),
        (lambda: Ball([0, 0], 0.0), "radius"),
        (lambda: Ball([0, 0], math.inf), "radius"),
        (lambda: Polygon([[0, 0], [1, 1]]), "at least 3"),
        (lambda: Polygon([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), "2D"),
        (lambda: Polygon([[0, 0], [1, 1], [1, 0], [0, 1]]), "not simple"),
        (lambda: Polygon([[0, 0], [1, 0], [2, 0]]), "folds back"),
        (lambda: Polygon([[0, 0], [1, 0], [1, 0], [0, 1]]), "repeated"),
    ],
)
def test_invalid_shapes_are_rejected(factory: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        factory()  # type: ignore[operator]


def test_shapes_are_frozen_and_comparable() -> None:
    box = Box([0, 0], [1, 2])
    with pytest.raises(dataclasses.FrozenInstanceError):
        box.lo = np.zeros(2)  # type: ignore[misc]
    with pytest.raises(ValueError):
        box.lo[0] = 5.0
    assert box == Box([0.0, 0.0], [1.0, 2.0]) and hash(box) == hash(Box([0, 0], [1, 2]))
    assert box != Box([0, 0], [1, 3])
    assert Ball([0, 0], 1) == Ball([0.0, 0.0], 1.0)
    closed = Polygon([[0, 0], [1, 0], [0, 1], [0, 0]])
    assert closed == Polygon([[0, 0], [1, 0], [0, 1]]) and closed.volume == pytest.approx(0.5)
    assert box.dim == 2 and Ball([0, 0, 0], 1).dim == 3 and closed.dim == 2
