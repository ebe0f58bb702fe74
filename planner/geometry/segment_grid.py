"""Pairs of 2D segments that may lie close together, found with a uniform grid.

A polygon's simplicity check needs every pair of edges closer than a tolerance; testing all
``m (m - 1) / 2`` pairs takes seconds and gigabytes at ten thousand edges. Here every edge is cut
into pieces no longer than one grid cell, each piece is put in the cells its (padded) bounding
box meets, and only edges that share a cell and whose padded bounding boxes overlap are paired.
Two edges within ``pad`` of each other always pass both tests, so the pairs are a superset of
the close ones: a check that measures them exactly is as exact as the quadratic one.

The cell size is the one of a few candidates (a ladder of halvings below the mean edge length)
with the least pieces plus shared-cell pairs. Work grows about linearly for the polygons a world
holds; edges packed far more densely than their length (thousands of long thin spikes) still
make many pairs, which admission limits on vertex counts keep small.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]

PAIR_CHUNK = 1 << 18
"""Candidate pairs produced at a time, so that memory stays bounded whatever the input."""

PIECES_PER_EDGE = 8
"""Finer cells are not tried once they would cut the edges into more pieces than this many
per edge (memory stays linear in the number of edges)."""


def _piece_cells(
    p: FloatArray, q: FloatArray, pad: float, cell: float
) -> tuple[IntArray, IntArray]:
    """Sorted, distinct ``(cell key, edge index)`` for every cell a padded piece meets."""
    origin = np.minimum(p, q).min(axis=0) - 2.0 * pad - cell
    length = np.linalg.norm(q - p, axis=1)
    pieces = np.maximum(np.ceil(length / cell), 1.0).astype(np.int64)
    edge = np.repeat(np.arange(len(p), dtype=np.int64), pieces)
    first = np.repeat(np.cumsum(pieces) - pieces, pieces)
    t = (np.arange(len(edge), dtype=np.int64) - first).astype(float)
    n = pieces[edge].astype(float)
    u = q[edge] - p[edge]
    a = p[edge] + (t / n)[:, None] * u
    b = p[edge] + ((t + 1.0) / n)[:, None] * u
    lo = np.floor((np.minimum(a, b) - pad - origin) / cell).astype(np.int64)
    hi = np.floor((np.maximum(a, b) + pad - origin) / cell).astype(np.int64)
    # cell >= 4 pad: a padded piece spans at most 1.5 cells, so three cells per axis at most.
    assert int((hi - lo).max()) <= 2
    width = int(hi[:, 1].max()) + 2
    keys, edges = [], []
    for dx in range(3):
        for dy in range(3):
            ix, iy = lo[:, 0] + dx, lo[:, 1] + dy
            inside = (ix <= hi[:, 0]) & (iy <= hi[:, 1])
            keys.append(ix[inside] * width + iy[inside])
            edges.append(edge[inside])
    key, edge = np.concatenate(keys), np.concatenate(edges)
    order = np.lexsort((edge, key))
    key, edge = key[order], edge[order]
    fresh = np.r_[True, (key[1:] != key[:-1]) | (edge[1:] != edge[:-1])]
    return key[fresh], edge[fresh]


def _partners(key: IntArray) -> IntArray:
    """For each entry of sorted ``key``, how many later entries share its cell."""
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    sizes = np.diff(np.r_[starts, len(key)])
    ends = np.repeat(starts + sizes, sizes)
    return np.asarray(ends - np.arange(len(key), dtype=np.int64) - 1)


def _best_grid(p: FloatArray, q: FloatArray, pad: float) -> tuple[IntArray, IntArray, IntArray]:
    """The cell entries and partner counts of the cheapest candidate cell size."""
    length = np.linalg.norm(q - p, axis=1)
    total = float(length.sum())
    cell = max(float(length.mean()), 4.0 * pad, 1e-300)
    best: tuple[int, IntArray, IntArray, IntArray] | None = None
    while True:
        key, edge = _piece_cells(p, q, pad, cell)
        later = _partners(key)
        cost = len(key) + int(later.sum())
        if best is None or cost < best[0]:
            best = (cost, key, edge, later)
        cell /= 2.0
        if cell < 4.0 * pad or total / cell > PIECES_PER_EDGE * len(p) or cost < 4 * len(p):
            break
    return best[1], best[2], best[3]


def near_segment_pairs(p: FloatArray, q: FloatArray, pad: float) -> Iterator[IntArray]:
    """Chunks of ``(k, 2)`` index pairs ``i < j`` of segments ``p[i]-q[i]``, ``p[j]-q[j]``
    whose padded bounding boxes overlap in a shared grid cell: every pair of segments within
    distance ``pad`` of each other is among them (a pair may appear in several chunks)."""
    m = len(p)
    if m < 2:
        return
    lo, hi = np.minimum(p, q) - pad, np.maximum(p, q) + pad
    key, edge, later = _best_grid(p, q, pad)
    reach = np.cumsum(later)
    begin = 0
    while begin < len(key):
        done = int(reach[begin - 1]) if begin else 0
        stop = max(int(np.searchsorted(reach, done + PAIR_CHUNK, side="right")), begin + 1)
        counts = later[begin:stop]
        total = int(counts.sum())
        begin, first_entry = stop, begin
        if not total:
            continue
        first = np.repeat(np.arange(first_entry, stop, dtype=np.int64), counts)
        offset = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
        i, j = edge[first], edge[first + 1 + offset]
        overlap = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
        i, j = i[overlap], j[overlap]
        code = np.sort(np.minimum(i, j) * m + np.maximum(i, j))
        code = code[np.r_[True, code[1:] != code[:-1]]] if len(code) else code
        if len(code):
            yield np.stack([code // m, code % m], axis=1)
