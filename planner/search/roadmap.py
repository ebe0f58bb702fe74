"""The verified edges a product tree has checked, and a warm start for suffix trees from them.

Every RRT* step checks the segments from the new point to its neighbours (collision free, at most
one label change) and forgets the answer. Kept, those segments form a roadmap of the space the
prefix tree explored. A suffix tree of TL-RRT* searches the same space in the product with other
automaton states, from the root ``(x*, q*)``: instead of rediscovering every passage by sampling
(a patrol's cycle must cross a narrow door twice), it starts as the shortest-path tree of the
product of that roadmap with the automaton (Dijkstra, scipy's csgraph), which is a valid product
tree: every node's parent reaches it by a checked segment and an automaton transition under the
label of the node's point. RRT* steps then grow and rewire it as usual.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra


class Roadmap:
    """Undirected geometric edges ``u - v`` of length ``d`` between point ids, as checked."""

    def __init__(self) -> None:
        self._u: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._d: list[np.ndarray] = []

    def record(self, u: int, v: np.ndarray, d: np.ndarray) -> None:
        """Segments from point ``u`` to points ``v`` (lengths ``d``) are valid edges."""
        self._u.append(np.full(len(v), u, dtype=np.int64))
        self._v.append(np.asarray(v, dtype=np.int64))
        self._d.append(np.asarray(d, dtype=float))

    def record_all(self, u: np.ndarray, v: np.ndarray, d: np.ndarray) -> None:
        """Edges ``u[i] - v[i]`` of lengths ``d[i]`` are valid."""
        self._u.append(np.asarray(u, dtype=np.int64))
        self._v.append(np.asarray(v, dtype=np.int64))
        self._d.append(np.asarray(d, dtype=float))

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, v, d) arrays of all the edges recorded."""
        if not self._u:
            empty = np.empty(0, dtype=np.int64)
            return empty, empty, np.empty(0)
        return np.concatenate(self._u), np.concatenate(self._v), np.concatenate(self._d)


def product_shortest_paths(
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    labels: np.ndarray,
    reach: np.ndarray,
    roots: list[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra from the product nodes ``roots`` (indices ``point * Q + state``) over the
    product of an undirected roadmap (edges ``u - v``, lengths ``d``) with an automaton:
    ``(a, q) -> (b, q')`` when ``a - b`` is an edge and ``reach[labels[b], q, q']``. Returns the
    (points, states) arrays of costs (inf: unreachable) and of predecessor product indices
    (negative where none)."""
    q_count = reach.shape[1]
    n_points = len(labels)
    u, v, d = _shortest_edges(u, v, d, n_points)
    back = u != v  # a loop is one directed edge already
    a = np.concatenate([u, v[back]])
    b = np.concatenate([v, u[back]])
    w = np.concatenate([d, d[back]])
    # Grouped by the label of the edge's head: each label's transitions are listed once, not
    # looked up per edge and state (edges x states^2 for any-order tasks of 2^k states).
    label_b = labels[b]
    none = np.empty(0, dtype=np.int64)
    rows, cols, weights = [none], [none], [np.empty(0)]
    for label in np.unique(label_b):
        edge = np.flatnonzero(label_b == label)
        q, q2 = np.nonzero(reach[label])
        rows.append((a[edge][:, None] * q_count + q).ravel())
        cols.append((b[edge][:, None] * q_count + q2).ravel())
        weights.append(np.repeat(w[edge], len(q)))
    size = n_points * q_count
    # Each geometric edge is there once and each (edge, q, q') once: no product edge repeats.
    graph = csr_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
        shape=(size, size),
    )
    cost, pred, _ = dijkstra(
        graph, directed=True, indices=roots, return_predecessors=True, min_only=True
    )
    return cost.reshape(n_points, q_count), pred.reshape(n_points, q_count)


def _shortest_edges(
    u: np.ndarray, v: np.ndarray, d: np.ndarray, n_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The roadmap's edges once each, as ``(low end, high end, least length)``: an edge is
    recorded again whenever a rewiring checks it."""
    low, high = np.minimum(u, v), np.maximum(u, v)
    key = low * n_points + high
    order = np.lexsort((d, key))
    key, d = key[order], d[order]
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    return low[order][first], high[order][first], d[first]
