"""Nearest and radius queries over a growing point set, sub-linear in its size.

The trees of TL-RRT* ask for the nearest point and for all points within the RRT* radius once per
iteration, over sets that grow by one point at a time. A scipy cKDTree cannot grow, so it covers
the points present at its last rebuild and the newer points (a tail of at most an eighth of the
set) are scanned with one vectorised distance computation. Rebuilding whenever the tail passes
an eighth of the set keeps the rebuild cost amortised O(log n) per insertion, and every query
O(log n + tail); results are exact and do not depend on when rebuilds happen.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

_MIN_TAIL = 256


class PointIndex:
    """Points with integer ids; ``nearest`` and ``within`` queries (see the module docstring)."""

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self._pts = np.empty((64, dim))
        self._ids = np.empty(64, dtype=np.int64)
        self.size = 0
        self._kd: cKDTree | None = None
        self._frozen = 0

    def add(self, pid: int, x: np.ndarray) -> None:
        """Insert point id ``pid`` at ``x``."""
        if self.size == len(self._ids):
            self._pts = np.concatenate([self._pts, np.empty_like(self._pts)])
            self._ids = np.concatenate([self._ids, np.empty_like(self._ids)])
        self._pts[self.size] = x
        self._ids[self.size] = pid
        self.size += 1
        self._rebuild_if_due()

    def add_many(self, pids: np.ndarray, xs: np.ndarray) -> None:
        """Insert the ids ``pids`` at the rows of ``xs``, in this order (as ``add`` one by one
        would: every query answers the same)."""
        end = self.size + len(pids)
        if end > len(self._ids):
            capacity = max(end, 2 * len(self._ids))
            self._pts = np.concatenate([self._pts, np.empty((capacity - len(self._ids), self.dim))])
            self._ids = np.concatenate([self._ids, np.empty(capacity - len(self._ids), np.int64)])
        self._pts[self.size : end] = xs
        self._ids[self.size : end] = pids
        self.size = end
        self._rebuild_if_due()

    def _rebuild_if_due(self) -> None:
        if self.size - self._frozen > max(_MIN_TAIL, self.size // 8):
            self._kd = cKDTree(self._pts[: self.size])
            self._frozen = self.size

    def nearest(self, x: np.ndarray) -> tuple[int, float]:
        """Id of the point nearest to ``x`` and its distance (the first inserted on a tie)."""
        best_i, best_d = -1, math.inf
        if self._kd is not None:
            d, i = self._kd.query(x)
            best_i, best_d = int(i), float(d)
        if self.size > self._frozen:
            diff = self._pts[self._frozen : self.size] - x
            d2 = np.einsum("ij,ij->i", diff, diff)
            j = int(np.argmin(d2))
            if d2[j] < best_d * best_d:
                best_i, best_d = self._frozen + j, math.sqrt(float(d2[j]))
        return int(self._ids[best_i]), best_d

    def within(self, x: np.ndarray, r: float, k: int | None = None) -> np.ndarray:
        """Ids of the points at distance <= r from ``x``; with ``k``, only the k nearest of
        them. Sorted by distance (ties, which random points do not produce, by position)."""
        d_parts, i_parts = [], []
        if self._kd is not None:
            if k is None:
                found = np.asarray(self._kd.query_ball_point(x, r), dtype=np.int64)
                diff = self._pts[found] - x
                d_parts.append(np.einsum("ij,ij->i", diff, diff))
                i_parts.append(found)
            else:
                dk, ik = self._kd.query(x, k=k, distance_upper_bound=r * (1.0 + 1e-12))
                hit = np.isfinite(dk)
                d_parts.append(dk[hit] ** 2)
                i_parts.append(ik[hit].astype(np.int64))
        if self.size > self._frozen:
            diff = self._pts[self._frozen : self.size] - x
            d2 = np.einsum("ij,ij->i", diff, diff)
            hit = np.flatnonzero(d2 <= r * r)
            d_parts.append(d2[hit])
            i_parts.append(self._frozen + hit)
        if not i_parts:
            return np.empty(0, dtype=np.int64)
        d2, idx = np.concatenate(d_parts), np.concatenate(i_parts)
        keep = d2 <= r * r
        d2, idx = d2[keep], idx[keep]
        order = np.lexsort((idx, d2))
        if k is not None:
            order = order[:k]
        return np.asarray(self._ids[idx[order]])
