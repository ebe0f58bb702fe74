"""The polygon simplicity check (grid of edges) against the all-pairs reference, and its speed."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.geometry.shapes import Polygon, first_close_edges, segment_segment_sqdist_2d


def reference_close_edges(p: np.ndarray, q: np.ndarray, tol: float) -> tuple[int, int] | None:
    """The former check: every pair of edges measured (quadratic)."""
    m = len(p)
    i, j = np.triu_indices(m, k=1)
    adjacent = (j == i + 1) | ((i == 0) & (j == m - 1))
    d2 = segment_segment_sqdist_2d(p[i], q[i], p[j], q[j])
    bad = (~adjacent) & (d2 <= tol * tol)
    if not np.any(bad):
        return None
    k = int(np.argmax(bad))
    return int(i[k]), int(j[k])


def _ring(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return vertices, np.roll(vertices, -1, axis=0)


# Small integer coordinates make touching vertices, collinear overlaps and crossings common.
integer_rings = st.lists(
    st.tuples(st.integers(-4, 4), st.integers(-4, 4)), min_size=3, max_size=14
).map(lambda pts: np.asarray(pts, dtype=float))
scaled_rings = st.tuples(
    integer_rings, st.floats(1e-3, 1e3), st.floats(-50, 50), st.floats(-50, 50)
).map(lambda a: a[0] * a[1] + np.array([a[2], a[3]]))


@settings(max_examples=400, deadline=None)
@given(scaled_rings)
def test_grid_finds_the_same_first_pair_as_all_pairs(vertices: np.ndarray) -> None:
    p, q = _ring(vertices)
    tol = 1e-12 * (float(np.abs(vertices).max()) + 1.0)
    assert first_close_edges(p, q, tol) == reference_close_edges(p, q, tol)


@settings(max_examples=200, deadline=None)
@given(st.integers(3, 60), st.integers(0, 2**31 - 1), st.floats(0.0, 0.95))
def test_grid_agrees_on_random_star_polygons(n: int, seed: int, jitter: float) -> None:
    """Star-shaped rings (simple, or made non-simple by shuffled angles) of many edges."""
    rng = np.random.default_rng(seed)
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    if rng.uniform() < 0.5:
        swap = rng.integers(0, n, 2)
        angles[swap] = angles[swap[::-1]]
    radii = 1.0 + jitter * rng.uniform(-1, 1, n)
    vertices = np.c_[radii * np.cos(angles), radii * np.sin(angles)]
    p, q = _ring(vertices)
    tol = 1e-12 * (float(np.abs(vertices).max()) + 1.0)
    assert first_close_edges(p, q, tol) == reference_close_edges(p, q, tol)


def test_a_polygon_of_twenty_thousand_vertices_is_checked_quickly() -> None:
    rng = np.random.default_rng(0)
    n = 20_000
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    radii = 10 + 0.01 * rng.uniform(size=n)
    vertices = np.c_[radii * np.cos(angles), radii * np.sin(angles)]
    t0 = time.process_time()
    Polygon(vertices)
    crossed = vertices.copy()
    crossed[[100, 101]] = crossed[[101, 100]]
    with pytest.raises(ValueError, match="edge 99 touches or crosses edge 101"):
        Polygon(crossed)
    assert time.process_time() - t0 < 5.0  # the all-pairs check took ~40 s and 20 GB
