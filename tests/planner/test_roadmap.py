"""The product Dijkstra over a roadmap whose edges were recorded several times."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra

from planner.search.roadmap import product_shortest_paths


def _brute_force(
    u: np.ndarray, v: np.ndarray, d: np.ndarray, labels: np.ndarray, reach: np.ndarray, root: int
) -> np.ndarray:
    """Costs by a dense product graph keeping the least length of every product edge."""
    q_count = reach.shape[1]
    size = len(labels) * q_count
    dense = np.full((size, size), np.inf)
    for a, b, w in zip([*u, *v], [*v, *u], [*d, *d], strict=True):
        for q in range(q_count):
            for q2 in np.flatnonzero(reach[labels[b], q]):
                i, j = a * q_count + q, b * q_count + q2
                dense[i, j] = min(dense[i, j], w)
    graph = np.where(np.isfinite(dense), dense, 0.0)
    cost: np.ndarray = dijkstra(graph, directed=True, indices=[root], min_only=True)
    return cost.reshape(len(labels), q_count)


def test_repeated_edges_and_loops_count_once_at_their_least_length() -> None:
    rng = np.random.default_rng(3)
    points, q_count, label_count = 30, 3, 2
    u = rng.integers(0, points, 200)
    v = rng.integers(0, points, 200)
    v[:5] = u[:5]  # loops: a state may change at a point
    d = rng.uniform(0.1, 2.0, 200)
    # Every edge again, reversed and longer, and again the other way at its length.
    u_all = np.concatenate([u, v, u])
    v_all = np.concatenate([v, u, v])
    d_all = np.concatenate([d, d + 1.0, d])
    labels = rng.integers(0, label_count, points)
    reach = rng.random((label_count, q_count, q_count)) < 0.5
    reach[:, np.arange(q_count), np.arange(q_count)] = True
    cost, pred = product_shortest_paths(u_all, v_all, d_all, labels, reach, roots=[0])
    expected = _brute_force(u_all, v_all, d_all, labels, reach, root=0)
    np.testing.assert_allclose(cost, expected)
    reached = np.isfinite(cost)
    assert reached.sum() > points  # the product spreads over several states
    assert ((pred >= 0) == reached).sum() == reached.size - 1  # every node but the root


def test_a_roadmap_without_edges_reaches_the_roots_alone() -> None:
    empty = np.empty(0, dtype=np.int64)
    reach = np.ones((2, 3, 3), dtype=bool)
    cost, pred = product_shortest_paths(empty, empty, np.empty(0), np.zeros(4, int), reach, [0])
    assert np.isfinite(cost).sum() == 1 and cost[0, 0] == 0.0
    assert (pred < 0).all()
