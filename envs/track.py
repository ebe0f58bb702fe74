"""The path a feed-forward follows along a leg (:class:`Track`) and the points on it that the
feed-forward laws of ``envs.feedforward`` aim at."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from planner.geometry.drivable import arc_lengths
from planner.guidance import Guide


@dataclass(frozen=True)
class Track:
    """The path the pursuit law follows along a leg: the dense drivable path where the guide
    was redrawn (``EnvOptions.drivable_guide``; its balls, ``2 r`` apart, cut the chord of a
    0.9 m arc up to 0.35 m inside it, enough to clip a box), else the guide's ball centres."""

    points: np.ndarray
    """``(m, d)`` points along the path."""
    togo: np.ndarray
    """``(m,)`` path length from each point to the end (non-increasing)."""
    ball_togo: np.ndarray
    """``(n,)`` path length from each of the guide's balls to the end."""
    cusp: int = 0
    """``points[: cusp + 1]`` are a reversing lead, driven backwards (0: none)."""
    slack: np.ndarray | None = None
    """``(m,)`` room between the robot and the obstacles at each point: their distance less the
    robot's radius (None: not measured)."""
    neg_togo: np.ndarray = field(init=False, repr=False, compare=False)
    """``-togo`` (non-decreasing, for ``searchsorted``)."""
    _stretches: dict[int, Stretch] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        object.__setattr__(self, "neg_togo", -np.asarray(self.togo, dtype=float))

    @classmethod
    def of_guide(cls, guide: Guide) -> Track:
        """The guide's ball centres."""
        return cls(guide.centers, guide.dist_to_go, guide.dist_to_go)

    @classmethod
    def dense(
        cls, points: np.ndarray, balls: int, cusp: int = 0, slack: np.ndarray | None = None
    ) -> Track:
        """``points``, a dense path whose ``balls`` marks evenly spaced along it are the
        guide's balls (``planner.geometry.drivable.thin``), driven backwards up to
        ``points[cusp]`` (0: no reversing lead), with the robot's ``slack`` at each point."""
        pts = np.asarray(points, dtype=float)
        along = arc_lengths(pts)
        total = float(along[-1])
        return cls(pts, total - along, total - np.linspace(0.0, total, balls), cusp, slack)

    def least_slack(self, near: float, far: float) -> float:
        """The least ``slack`` of the points from ``near`` down to ``far`` metres to go, or of
        the point nearest to them (inf: not measured)."""
        if self.slack is None:
            return math.inf
        lo = min(int(np.searchsorted(self.neg_togo, -near, side="left")), len(self.slack) - 1)
        hi = int(np.searchsorted(self.neg_togo, -far, side="right"))
        return float(self.slack[lo : max(hi, lo + 1)].min())

    @property
    def cusp_togo(self) -> float | None:
        """Path length from the end of the reversing lead to the end (None: no lead)."""
        return float(self.togo[self.cusp]) if self.cusp > 0 else None

    @property
    def lead(self) -> Stretch:
        """The segments of the reversing lead (worked out once)."""
        found = self._stretches.get(-2)
        if found is None:
            found = self._stretches[-2] = Stretch.between(self.points, 0, max(self.cusp, 1))
        return found

    def stretch(self, index: int) -> Stretch:
        """The segments of the track from ball ``index - 1`` to ball ``index + 4`` (``index``
        -1: none reached), worked out once per index: the pursuit law asks every step."""
        found = self._stretches.get(index)
        if found is None:
            found = self._stretches[index] = Stretch.of(self, index)
        return found


@dataclass(frozen=True)
class Stretch:
    """Segments ``lo`` to ``lo + len(a) - 1`` of a track: their starts ``a``, vectors ``seg``,
    squared lengths (at least 1e-18) and lengths."""

    lo: int
    a: np.ndarray
    seg: np.ndarray
    length_sq: np.ndarray
    length: np.ndarray

    @classmethod
    def of(cls, track: Track, index: int) -> Stretch:
        points, neg_togo = track.points, track.neg_togo
        m, n = len(points), len(track.ball_togo)
        far = track.ball_togo[max(index - 1, 0)]
        near = track.ball_togo[min(max(index, 0) + 4, n - 1)]
        lo = min(max(int(np.searchsorted(neg_togo, -far, side="right")) - 1, 0), m - 2)
        hi = max(min(int(np.searchsorted(neg_togo, -near, side="left")), m - 1), lo + 1)
        return cls.between(points, lo, hi)

    @classmethod
    def between(cls, points: np.ndarray, lo: int, hi: int) -> Stretch:
        """Segments ``lo`` to ``hi - 1`` of the path ``points``."""
        a, seg = points[lo:hi], points[lo + 1 : hi + 1] - points[lo:hi]
        length_sq = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-18)
        return cls(lo, a, seg, length_sq, np.sqrt(length_sq))


def pursuit_target(
    track: Track, index: int, x: Sequence[float] | np.ndarray, ahead: float
) -> np.ndarray:
    """The point ``ahead`` metres along ``track`` past the projection of ``x`` on its stretch
    from ball ``index - 1`` to ball ``index + 4`` (``index`` -1: none reached)."""
    return point_to_go(track, projected_togo(track, index, x) - ahead)


def projected_togo(track: Track, index: int, x: Sequence[float] | np.ndarray) -> float:
    """Path length to the end of ``track`` from the projection of ``x`` on its stretch from
    ball ``index - 1`` to ball ``index + 4``."""
    if len(track.points) == 1:
        return 0.0
    return _projected(track.stretch(index), track.togo, x)


def lead_togo(track: Track, x: Sequence[float] | np.ndarray) -> float:
    """Path length to the end of ``track`` from the projection of ``x`` on its reversing lead
    alone (where the rest of the path passes near the lead, it must not capture ``x``)."""
    return _projected(track.lead, track.togo, x)


def _projected(st: Stretch, togo: np.ndarray, x: Sequence[float] | np.ndarray) -> float:
    point = np.asarray(x, dtype=float)
    t = np.clip(np.einsum("ij,ij->i", point - st.a, st.seg) / st.length_sq, 0.0, 1.0)
    gap = st.a + t[:, None] * st.seg - point
    j = int(np.argmin(np.einsum("ij,ij->i", gap, gap)))
    return float(togo[st.lo + j]) - t[j] * float(st.length[j])


def point_to_go(track: Track, left: float) -> np.ndarray:
    """The point of ``track`` with path length ``left`` to its end."""
    points, togo = track.points, track.togo
    m = len(points)
    k = int(np.searchsorted(track.neg_togo, -left, side="right"))
    if k >= m or m == 1:
        return np.asarray(points[-1], dtype=float)
    k = max(k, 1)
    span = float(togo[k - 1] - togo[k])
    share = (float(togo[k - 1]) - left) / span if span > 0 else 1.0
    return np.asarray(points[k - 1] + min(max(share, 0.0), 1.0) * (points[k] - points[k - 1]))


def lead_target(track: Track, left: float) -> np.ndarray:
    """The point of ``track``'s lead with path length ``left`` to its end, past the cusp on the
    line the lead ends along: backing towards it, the car no longer circles onto the cusp."""
    end = track.cusp
    over = float(track.togo[end]) - left
    if over <= 0 or end < 1:
        return point_to_go(track, left)
    direction = track.points[end] - track.points[end - 1]
    length = float(np.linalg.norm(direction))
    if length == 0:
        return np.asarray(track.points[end], dtype=float)
    return np.asarray(track.points[end] + over * direction / length, dtype=float)
