"""Fast paths against their references on random inputs: ray casts (the matrix path against
the general per-kind path and a brute-force march along each ray), ``Guide.locate`` against
``ball_index`` and a brute-force search, ``ProgressTracker.update_one`` against ``update``."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from envs.rays import RayCaster
from planner.geometry.shapes import Ball, Box, Polygon, Shape
from planner.geometry.world import World
from planner.guidance import Guide, ProgressTracker


def random_world(dim: int, seed: int) -> World:
    """30 boxes, 30 balls and (2D) 6 star-shaped, mostly non-convex polygons."""
    rng = np.random.default_rng(seed)
    extent = np.array([10.0, 10.0, 4.0][:dim])
    shapes: list[Shape] = []
    for _ in range(30):
        centre, half = rng.uniform(0.0, extent), rng.uniform(0.1, 0.6, size=dim)
        shapes.append(Box(centre - half, centre + half))
        shapes.append(Ball(rng.uniform(0.0, extent), float(rng.uniform(0.1, 0.6))))
    if dim == 2:
        for _ in range(6):
            angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, size=7))
            radii = rng.uniform(0.2, 0.8, size=7)
            ring = np.stack([np.cos(angles), np.sin(angles)], axis=1) * radii[:, None]
            shapes.append(Polygon(rng.uniform(1.0, 9.0, size=2) + ring))
    return World(np.stack([np.zeros(dim), extent], axis=1), shapes, {})


def ray_vectors(caster: RayCaster, rotation: tuple[float, float] | None) -> np.ndarray:
    if rotation is None:
        return caster.directions
    c, s = rotation
    return caster.directions @ np.array([[c, s], [-s, c]])


def samples(world: World, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Uniform points in the bounds, a few on box corners' lines, in boxes and outside."""
    lo, hi = world.bounds[:, 0], world.bounds[:, 1]
    pts = list(rng.uniform(lo, hi, size=(n, world.dim)))
    boxes = [s for s in world.obstacles if isinstance(s, Box)]
    pts += [(b.lo + b.hi) / 2.0 for b in boxes[:5]]  # inside a box: the general path
    pts += [b.lo.copy() for b in boxes[5:10]]  # on a box corner
    pts += [lo - 0.3, hi + 0.2, np.where(np.arange(world.dim) == 0, lo, hi / 2)]  # outside/on
    return pts


@pytest.mark.parametrize("dim", [2, 3])
def test_fast_rays_equal_the_general_cast(dim: int) -> None:
    world = random_world(dim, seed=dim)
    rng = np.random.default_rng(10 + dim)
    hits = 0
    for count, max_range in ((8, 2.5), (13, 6.0)):
        caster = RayCaster(world, count, max_range)
        for x in samples(world, rng, 300):
            rotation = None
            if dim == 2 and rng.random() < 0.8:
                angle = rng.uniform(-math.pi, math.pi)
                rotation = (math.cos(angle), math.sin(angle))
            fast = caster.cast(x.tolist(), rotation)
            general = caster.cast_general(x.tolist(), rotation)
            if (general < 0.0).any():  # outside the bounds: the general path itself
                assert np.array_equal(fast, general)
            else:
                np.testing.assert_allclose(fast, general, rtol=0.0, atol=1e-9)
            general = np.clip(general, 0.0, max_range)
            scaled = caster.cast_scaled(x.tolist(), rotation)
            np.testing.assert_allclose(scaled, general / max_range, rtol=0.0, atol=1e-9)
            hits += int((fast < max_range).sum())
    assert hits > 1000


@pytest.mark.parametrize("dim", [2, 3])
def test_fast_rays_match_a_march_along_each_ray(dim: int) -> None:
    """Independent of both casts: the path up to the reported distance is free, and just
    beyond it (when below the range) the ray is in an obstacle or out of the bounds."""
    world = random_world(dim, seed=20 + dim)
    rng = np.random.default_rng(30 + dim)
    caster = RayCaster(world, 12, 3.0)
    checked = 0
    for x in rng.uniform(world.bounds[:, 0], world.bounds[:, 1], size=(150, dim)):
        if world.in_collision(x[None, :])[0]:
            continue
        rotation = None
        if dim == 2:
            angle = rng.uniform(-math.pi, math.pi)
            rotation = (math.cos(angle), math.sin(angle))
        distances = caster.cast(x.tolist(), rotation)
        for u, t in zip(ray_vectors(caster, rotation), distances, strict=True):
            steps = np.linspace(0.0, max(t - 1e-7, 0.0), 400)[:, None]
            assert not world.in_collision(x + steps * u).any()
            if t < caster.max_range - 1e-9:
                assert world.in_collision((x + (t + 1e-6) * u)[None, :])[0]
                checked += 1
    assert checked > 300


def brute_index(guide: Guide, points: np.ndarray) -> np.ndarray:
    """Highest-indexed ball containing each point (least distance-to-go), -1 if none."""
    inside = ((points[:, None, :] - guide.centers[None]) ** 2).sum(-1) <= guide.r**2
    last = guide.num_balls - 1 - np.argmax(inside[:, ::-1], axis=1)
    return np.where(inside.any(axis=1), last, -1)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_locate_equals_ball_index_everywhere(dim: int) -> None:
    rng = np.random.default_rng(40 + dim)
    path = np.cumsum(rng.normal(size=(40, dim)) * 0.5, axis=0)
    guide = Guide.from_path(path, r=0.35)
    near = guide.centers[rng.integers(0, guide.num_balls, 3000)]
    near = near + rng.normal(size=near.shape) * 0.3
    lo, hi = path.min(axis=0), path.max(axis=0)
    # far outside the ball grid too: keys of such points may name other cells
    far = rng.uniform(lo - 2.0 * (hi - lo) - 5.0, hi + 2.0 * (hi - lo) + 5.0, size=(1500, dim))
    pts = np.concatenate([near, far, guide.centers])
    expected = brute_index(guide, pts)
    assert (expected >= 0).sum() > 1000 and (expected < 0).sum() > 1000
    np.testing.assert_array_equal(guide.ball_index(pts), expected)
    assert [guide.locate(p) for p in pts.tolist()] == expected.tolist()
    assert [guide.locate(p) for p in pts[:100]] == expected[:100].tolist()


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_update_one_equals_the_batch_update_and_keeps_arrays_in_sync(dim: int) -> None:
    rng = np.random.default_rng(50 + dim)
    guide = Guide.from_path(np.cumsum(rng.normal(size=(15, dim)), axis=0), r=0.4)
    envs = 5
    batch, scalar = ProgressTracker(guide, envs), ProgressTracker(guide, envs)
    scalar.reset(start_index=np.array([0, 1, 2, 0, 0]))
    batch.reset(start_index=np.array([0, 1, 2, 0, 0]))
    along = np.minimum(np.arange(150)[:, None] // 3 + np.arange(envs)[None], guide.num_balls - 1)
    walk = guide.centers[along] + rng.normal(size=(150, envs, dim)) * 0.35
    improved = 0
    for k, pts in enumerate(walk):
        step = batch.update(pts)
        for e in range(envs):
            point = pts[e] if k % 2 else pts[e].tolist()
            got = scalar.update_one(e, point)
            assert got == (bool(step.improved[e]), int(step.index[e]), float(step.d[e]))
            assert type(got[1]) is int and type(got[2]) is float
        np.testing.assert_array_equal(scalar.index, batch.index)
        np.testing.assert_array_equal(scalar.d_min, batch.d_min)
        improved += int(step.improved.sum())
        if k == 70:  # batch paths refresh the scalar mirrors
            for tracker in (scalar, batch):
                tracker.reset([1, 3])
                tracker.update(pts)
    assert improved >= 2 * envs
    with pytest.raises(ValueError):
        scalar.index[0] = 3  # read-only: in-place writes would bypass the scalar mirrors
    scalar.index = np.full(envs, guide.num_balls - 1)
    scalar.d_min = np.zeros(envs)
    point = guide.centers[0].tolist()
    i = guide.locate(point)
    assert scalar.update_one(0, point) == (False, guide.num_balls - 1, guide.dist_to_go[i])


def test_tracker_copies_stay_consistent() -> None:
    """Pickled or deep-copied trackers keep their scalar mirrors and arrays together."""
    guide = Guide.from_path(np.array([[0.0, 0.0], [2.0, 0.0]]), r=0.25)
    tracker = ProgressTracker(guide, 2)
    tracker.update_one(1, [1.0, 0.0])
    for twin in (copy.deepcopy(tracker), pickle.loads(pickle.dumps(tracker))):
        assert twin.update_one(1, [1.5, 0.0]) == (True, 3, 0.5)
        assert twin.index.tolist() == [-1, 3] and twin.d_min.tolist() == [math.inf, 0.5]
    assert tracker.index.tolist() == [-1, 2] and tracker.d_min.tolist() == [math.inf, 1.0]
