"""The r-ball guide of a sub-task and its progress tracker (the paper's reward on top of them is
``envs.rewards``).

A guide is the planned geometric path of one sub-task covered by balls of radius ``r``
centred on waypoints at most ``spacing`` apart (the paper uses touching balls, spacing
``2 r`` with ``r = eta / 2``). Ball ``i`` carries ``dist_to_go[i]``, the path length from its
centre to the end of the guide. The progress measure of a workspace point is

    D(x) = min { dist_to_go[i] : x in ball i },   D(x) = inf outside every ball,

and the progress index ``i_t`` is the ball with the least distance-to-go reached so far; keeping
it in the state makes the reward Markovian (Cai et al., RA-L 2023).

A guide that comes back near itself (a loop, a U-turn) has balls far apart in distance-to-go
that overlap; there the global minimum lets a point "reach" the end of the loop from its start.
A tracker with a ``window`` counts a ball only when it lies at most ``window`` balls past the
progress index: a point moving along the guide enters its balls in order, so this never holds
back real progress, and it cannot skip the loop.

The envs layer calls this on every simulation step, so both paths are cheap: a vectorised batch
path (a uniform grid of cell size ``2 r`` maps each cell to the few balls overlapping it, so a
query costs O(balls per cell), not O(balls)) and a pure-Python scalar path for one point that
costs a couple of microseconds.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

_floor = math.floor
_INF = math.inf


def _resample(path: np.ndarray, spacing: float) -> np.ndarray:
    """Keep every waypoint and insert evenly spaced points so that gaps are <= spacing."""
    out = [path[0]]
    for a, b in itertools.pairwise(path):
        length = float(np.linalg.norm(b - a))
        pieces = max(1, math.ceil(length / spacing - 1e-9))
        for k in range(1, pieces + 1):
            out.append(a + (b - a) * (k / pieces))
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Guide:
    """Balls of radius ``r`` along a guide path and their distance-to-go.

    Build with :meth:`from_path`. ``centers`` is ``(m, d)``; ``dist_to_go`` is ``(m,)``,
    non-increasing, 0 at the last ball. Since it is non-increasing, the ball realising the
    minimum in ``D(x)`` is the highest-indexed ball containing ``x``.
    """

    centers: np.ndarray
    dist_to_go: np.ndarray
    r: float
    _origin: np.ndarray = field(repr=False)
    _origin_t: tuple[float, ...] = field(repr=False)
    _cell: float = field(repr=False)
    _inv_cell: float = field(repr=False)
    _rr: float = field(repr=False)
    _strides: np.ndarray = field(repr=False)
    _shape: np.ndarray = field(repr=False)
    _keys: np.ndarray = field(repr=False)
    _table: np.ndarray = field(repr=False)
    _buckets: dict[tuple[int, ...], tuple[tuple[int, tuple[float, ...]], ...]] = field(repr=False)
    _flat: tuple[Any, ...] = field(repr=False)
    """2D/3D scalar path: ``(o_0, .., o_d-1, 1 / cell, stride_0, .., stride_d-1, r^2)``."""
    _flat_buckets: dict[int, tuple[tuple[Any, ...], ...]] = field(repr=False)
    """Flattened cell key -> ``(i, c_0, .., c_d-1)`` of the balls meeting the cell, highest
    index first."""

    @classmethod
    def from_path(cls, path: np.ndarray, r: float, spacing: float | None = None) -> Guide:
        """Guide of ``path`` ``(n, d)`` with balls of radius ``r`` at most ``spacing`` apart
        (default ``2 r``: touching balls). Repeated consecutive waypoints are dropped."""
        pts = np.asarray(path, dtype=np.float64)
        if pts.ndim != 2 or len(pts) == 0:
            raise ValueError("a guide path must be a non-empty (n, d) array")
        if not r > 0:
            raise ValueError("the ball radius r must be > 0")
        step = 2.0 * r if spacing is None else float(spacing)
        if not step > 0:
            raise ValueError("the ball spacing must be > 0")
        keep = np.ones(len(pts), dtype=bool)
        keep[1:] = np.any(pts[1:] != pts[:-1], axis=1)
        pts = pts[keep]
        centers = _resample(pts, step) if len(pts) > 1 else pts.copy()
        seg = np.linalg.norm(np.diff(centers, axis=0), axis=1)
        dist = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
        return cls._build(centers, dist, float(r))

    @classmethod
    def _build(cls, centers: np.ndarray, dist: np.ndarray, r: float) -> Guide:
        cell = 2.0 * r
        origin = centers.min(axis=0) - r
        lo = np.floor((centers - r - origin) / cell).astype(np.int64)
        hi = np.floor((centers + r - origin) / cell).astype(np.int64)
        shape = hi.max(axis=0) + 1
        members: dict[tuple[int, ...], list[int]] = {}
        for i in range(len(centers)):
            ranges = [range(int(a), int(b) + 1) for a, b in zip(lo[i], hi[i], strict=True)]
            for key in itertools.product(*ranges):
                members.setdefault(key, []).append(i)
        # Highest index first: the first ball found that contains x is the one with least D.
        buckets = {
            key: tuple((i, tuple(float(v) for v in centers[i])) for i in sorted(ids, reverse=True))
            for key, ids in members.items()
        }
        keys_sorted = sorted(members)
        width = max(len(v) for v in members.values())
        table = np.full((len(keys_sorted), width), -1, dtype=np.int64)
        for row, key in enumerate(keys_sorted):
            ids = sorted(members[key], reverse=True)
            table[row, : len(ids)] = ids
        strides = np.cumprod(np.concatenate([[1], shape[::-1][:-1]]))[::-1]
        flat = np.array([int(np.dot(k, strides)) for k in keys_sorted], dtype=np.int64)
        flat_buckets = {
            int(np.dot(key, strides)): tuple((i, *c) for i, c in bucket)
            for key, bucket in buckets.items()
        }
        return cls(
            centers=centers,
            dist_to_go=dist,
            r=r,
            _origin=origin,
            _origin_t=tuple(origin.tolist()),
            _cell=cell,
            _inv_cell=1.0 / cell,
            _rr=r * r,
            _strides=strides,
            _shape=shape,
            _keys=flat,
            _table=table,
            _buckets=buckets,
            _flat=(*origin.tolist(), 1.0 / cell, *(int(v) for v in strides), r * r),
            _flat_buckets=flat_buckets,
        )

    @property
    def num_balls(self) -> int:
        """Number of r-balls."""
        return len(self.centers)

    @property
    def length(self) -> float:
        """Path length of the guide (distance-to-go of its first ball)."""
        return float(self.dist_to_go[0])

    def ball_index(self, points: np.ndarray, limit: np.ndarray | None = None) -> np.ndarray:
        """``(n,)`` index of the ball realising ``D(x)`` for each point, -1 in no ball; with
        ``limit`` ``(n,)``, among the balls of index at most ``limit`` only."""
        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        cells = np.floor((pts - self._origin) / self._cell).astype(np.int64)
        inside = np.all((cells >= 0) & (cells < self._shape), axis=1)
        flat = np.where(inside, cells @ self._strides, -1)
        row = np.searchsorted(self._keys, flat)
        row = np.minimum(row, len(self._keys) - 1)
        hit = inside & (self._keys[row] == flat)
        cand = np.where(hit[:, None], self._table[row], -1)
        diff = self.centers[np.maximum(cand, 0)] - pts[:, None, :]
        ok = (cand >= 0) & (np.einsum("nkd,nkd->nk", diff, diff) <= self._rr)
        if limit is not None:
            ok &= cand <= np.asarray(limit)[:, None]
        first = np.argmax(ok, axis=1)
        return np.where(ok.any(axis=1), cand[np.arange(len(pts)), first], -1)

    def distance_to_go(self, points: np.ndarray) -> np.ndarray:
        """``(n,)`` progress measure ``D(x)``: least distance-to-go of a ball containing x,
        ``inf`` outside every ball."""
        idx = self.ball_index(points)
        return np.where(idx >= 0, self.dist_to_go[np.maximum(idx, 0)], np.inf)

    def locate(
        self, point: np.ndarray | tuple[float, ...] | list[float], limit: int | None = None
    ) -> int:
        """Scalar :meth:`ball_index` of one point in pure Python (well under a microsecond in
        2D and 3D); with ``limit``, among the balls of index at most ``limit`` only."""
        xs = point.tolist() if isinstance(point, np.ndarray) else point
        top = self.num_balls if limit is None else limit
        if len(xs) == 2 == len(self._origin_t):
            return _locate2(self, xs[0], xs[1], top)
        if len(xs) == 3 == len(self._origin_t):
            return _locate3(self, xs[0], xs[1], xs[2], top)
        inv = self._inv_cell
        key = tuple([math.floor((v - o) * inv) for v, o in zip(xs, self._origin_t, strict=False)])
        bucket = self._buckets.get(key)
        if bucket is None:
            return -1
        rr = self._rr
        for i, c in bucket:
            if i > top:
                continue
            s = 0.0
            for v, w in zip(xs, c, strict=False):
                s += (v - w) * (v - w)
            if s <= rr:
                return i
        return -1


def _locate2(guide: Guide, x0: float, x1: float, top: int) -> int:
    """:meth:`Guide.locate` of a 2D point. A key computed for a point outside the grid may name
    another cell, but no ball contains such a point and every candidate is tested exactly."""
    o0, o1, inv, s0, s1, rr = guide._flat
    bucket = guide._flat_buckets.get(
        math.floor((x0 - o0) * inv) * s0 + math.floor((x1 - o1) * inv) * s1
    )
    if bucket is not None:
        for i, c0, c1 in bucket:
            if i <= top and (x0 - c0) * (x0 - c0) + (x1 - c1) * (x1 - c1) <= rr:
                return i
    return -1


def _locate3(guide: Guide, x0: float, x1: float, x2: float, top: int) -> int:
    """:meth:`Guide.locate` of a 3D point (see :func:`_locate2`)."""
    o0, o1, o2, inv, s0, s1, s2, rr = guide._flat
    bucket = guide._flat_buckets.get(
        math.floor((x0 - o0) * inv) * s0
        + math.floor((x1 - o1) * inv) * s1
        + math.floor((x2 - o2) * inv) * s2
    )
    if bucket is not None:
        for i, c0, c1, c2 in bucket:
            if i > top:
                continue
            if (x0 - c0) * (x0 - c0) + (x1 - c1) * (x1 - c1) + (x2 - c2) * (x2 - c2) <= rr:
                return i
    return -1


@dataclass(frozen=True)
class StepProgress:
    """Result of one tracker update over a batch: ``improved`` (a new minimum of D was
    reached), ``index`` (the progress index after the step, -1 before any ball) and ``d``
    (``D(x_t)`` of the current point, ``inf`` outside the balls)."""

    improved: np.ndarray
    index: np.ndarray
    d: np.ndarray

    @property
    def at_end(self) -> np.ndarray:
        """The current point lies in the last ball (``D = 0``)."""
        return self.d == 0.0


class ProgressTracker:
    """Progress index ``i_t`` and ``D_min`` for a batch of ``num_envs`` envs along one guide.

    ``reset`` starts envs afresh (optionally at ball ``k``, for a start-state curriculum);
    ``update`` consumes the new points and reports which envs made progress. With ``window``,
    only balls at most that many past an env's progress index count (see the module
    docstring); None: every ball, the paper's ``D``.
    ``update_one`` is the allocation-free scalar path for one env: it reads plain Python
    mirrors of ``index`` and ``d_min`` and writes both on progress. The arrays are therefore
    read-only views; assign a whole new array (``tracker.index = ...``) to change them.
    """

    def __init__(self, guide: Guide, num_envs: int = 1, window: int | None = None) -> None:
        if window is not None and window < 1:
            raise ValueError("the progress window must be >= 1 ball")
        self.guide = guide
        self.num_envs = num_envs
        self.window = window
        self._reach = window if window is not None else guide.num_balls
        self._index = np.full(num_envs, -1, dtype=np.int64)
        self._d_min = np.full(num_envs, np.inf)
        self._index_list: list[int] = self._index.tolist()
        self._d_min_list: list[float] = self._d_min.tolist()
        self._dist = guide.dist_to_go.tolist()
        self._flat = guide._flat
        self._buckets = guide._flat_buckets
        dim = guide.centers.shape[1]
        self._dim = dim if dim in (2, 3) else 0

    @property
    def index(self) -> np.ndarray:
        """``(num_envs,)`` progress index per env (-1 before any ball); read-only view."""
        return _read_only(self._index)

    @index.setter
    def index(self, value: np.ndarray) -> None:
        self._index[:] = value
        self._index_list = self._index.tolist()

    @property
    def d_min(self) -> np.ndarray:
        """``(num_envs,)`` least distance-to-go reached per env (inf before any ball);
        read-only view."""
        return _read_only(self._d_min)

    @d_min.setter
    def d_min(self, value: np.ndarray) -> None:
        self._d_min[:] = value
        self._d_min_list = self._d_min.tolist()

    def reset(
        self,
        envs: np.ndarray | list[int] | int | None = None,
        start_index: int | np.ndarray | None = None,
        points: np.ndarray | None = None,
    ) -> None:
        """Reset the envs selected by ``envs`` (boolean mask, indices or one index; all when
        None). With ``start_index`` the progress index is set to that ball (and ``D_min`` to its
        distance-to-go); with ``points`` (one per selected env) it is set to the ball each point
        lies in; otherwise to "no ball yet" (-1, ``D_min = inf``)."""
        sel = np.arange(self.num_envs) if envs is None else np.asarray(envs)
        if sel.dtype == bool:
            sel = np.flatnonzero(sel)
        sel = np.atleast_1d(sel)
        if start_index is not None:
            idx = np.broadcast_to(np.asarray(start_index, dtype=np.int64), sel.shape)
            if np.any((idx < 0) | (idx >= self.guide.num_balls)):
                raise ValueError("start_index must name a ball of the guide")
        elif points is not None:
            pts = np.asarray(points).reshape(len(sel), -1)
            idx = self.guide.ball_index(pts, np.full(len(sel), self._reach - 1))
        else:
            idx = np.full(sel.shape, -1, dtype=np.int64)
        self._index[sel] = idx
        self._d_min[sel] = np.where(idx >= 0, self.guide.dist_to_go[np.maximum(idx, 0)], np.inf)
        self._index_list = self._index.tolist()
        self._d_min_list = self._d_min.tolist()

    def locate(self, point: np.ndarray | tuple[float, ...] | list[float], after: int = -1) -> int:
        """The ball of ``point`` this tracker would count for an env at progress index
        ``after`` (-1: before any ball); -1 in none."""
        return self.guide.locate(point, after + self._reach)

    def update(self, points: np.ndarray) -> StepProgress:
        """Consume one point per env ``(num_envs, d)``; a point improves when its ``D`` is
        strictly below the env's ``D_min`` so far."""
        idx = self.guide.ball_index(points, self._index + self._reach)
        d = np.where(idx >= 0, self.guide.dist_to_go[np.maximum(idx, 0)], np.inf)
        improved = d < self._d_min
        self._d_min[:] = np.where(improved, d, self._d_min)
        self._index[:] = np.where(improved, idx, self._index)
        self._index_list = self._index.tolist()
        self._d_min_list = self._d_min.tolist()
        return StepProgress(improved=improved, index=self._index.copy(), d=d)

    def update_one(
        self, env: int, point: np.ndarray | tuple[float, ...] | list[float]
    ) -> tuple[bool, int, float]:
        """Scalar :meth:`update` of env ``env``: ``(improved, index, d)``."""
        top = self._index_list[env] + self._reach
        if self._dim == 2:
            # _locate2 inlined: this runs on every env step.
            x0, x1 = point[0], point[1]
            o0, o1, inv, s0, s1, rr = self._flat
            i = -1
            bucket = self._buckets.get(_floor((x0 - o0) * inv) * s0 + _floor((x1 - o1) * inv) * s1)
            if bucket is not None:
                for j, c0, c1 in bucket:
                    dx, dy = x0 - c0, x1 - c1
                    if j <= top and dx * dx + dy * dy <= rr:
                        i = j
                        break
        elif self._dim == 3:
            i = _locate3(self.guide, point[0], point[1], point[2], top)
        else:
            i = self.guide.locate(point, top)
        if i < 0:
            return False, self._index_list[env], _INF
        d = self._dist[i]
        if d < self._d_min_list[env]:
            self._d_min_list[env] = d
            self._index_list[env] = i
            self._d_min[env] = d
            self._index[env] = i
            return True, i, d
        return False, self._index_list[env], d


def _read_only(array: np.ndarray) -> np.ndarray:
    """A fresh read-only view (made per access, so copies and pickles of a tracker stay
    consistent)."""
    view = array.view()
    view.flags.writeable = False
    return view
