"""The label function: scalar region tests and ``L(x)`` one point at a time."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from planner.geometry.region_test import RegionTest
from planner.geometry.shapes import Ball, Box, Polygon
from tests.planner.test_tl_rrt_star import world_2d


@pytest.mark.parametrize(
    "shape",
    [
        Box(np.array([1.0, -1.0]), np.array([2.0, 0.5])),
        Box(np.array([1.0, -1.0, 0.0]), np.array([2.0, 0.5, 1.0])),
        Ball(np.array([0.5, 0.2]), 0.7),
        Ball(np.array([0.5, 0.2, -0.3]), 0.7),
        Polygon(np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.5], [1.0, 2.0]])),
    ],
    ids=["box2", "box3", "ball2", "ball3", "polygon"],
)
def test_region_tests_agree_with_the_shapes(shape: Box | Ball | Polygon) -> None:
    test = RegionTest(shape)
    pts = np.random.default_rng(0).uniform(-1.0, 3.0, size=(300, shape.dim))
    inside = shape.contains(pts)
    assert 0 < inside.sum() < len(pts)
    assert [test.contains(p.tolist()) for p in pts] == inside.tolist()
    assert np.allclose([test.distance(p.tolist()) for p in pts], shape.distance(pts))


def test_labeler_matches_the_world_labels() -> None:
    world = world_2d()
    labeler = world.labeler
    points = np.random.default_rng(1).uniform(0.0, 10.0, size=(400, 2))
    for x in points:
        assert labeler.point_labels(x.tolist()) == world.labels(x) - {"obstacle"}
    matrix = world.label_matrix(points)
    for x, row in zip(points, matrix, strict=True):
        in_row = {n for n, inside in zip(world.region_names, row, strict=True) if inside}
        assert labeler.point_labels(x.tolist()) == in_row


def test_a_world_pickles_with_its_labeler() -> None:
    world = world_2d()
    again = pickle.loads(pickle.dumps(world))
    for x in np.random.default_rng(2).uniform(0.0, 10.0, size=(100, 2)):
        assert again.labels(x) == world.labels(x)
