"""Dubins paths: the shortest ways between two planar poses for a car that only drives forward
and turns no tighter than a radius ``rho``.

Every such path is one of six words of three segments, each a left arc (``L``), a right arc
(``R``) or a straight line (``S``): LSL, RSR, LSR, RSL, RLR and LRL (Dubins 1957). The closed
forms are those of Shkel and Lumelsky (2001), in the normalised frame where the start sits at
the origin, the goal on the positive x axis at distance ``d = D / rho`` and the radius is 1.
:func:`dubins_words` gives every feasible word, shortest first, so a caller that finds the
shortest one blocked by an obstacle can try the next; :meth:`DubinsPath.sample` turns a word
into points and headings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.geometry.pose import Pose

TWO_PI = 2.0 * math.pi
WORDS = ("LSL", "RSR", "LSR", "RSL", "RLR", "LRL")
"""The six Dubins words."""


@dataclass(frozen=True)
class DubinsPath:
    """One Dubins word from ``start`` with turning radius ``rho``: segment ``k`` of type
    ``word[k]`` runs ``segments[k]`` radians of arc (L, R) or ``segments[k] * rho`` metres of
    line (S)."""

    start: Pose
    word: str
    segments: tuple[float, float, float]
    rho: float

    @property
    def length(self) -> float:
        """Path length in metres."""
        return self.rho * sum(self.segments)

    def end(self) -> Pose:
        """The pose at the end of the path."""
        x, y, theta = _unpack(self.start)
        for kind, t in zip(self.word, self.segments, strict=True):
            x, y, theta = _advance(kind, t * self.rho, self.rho, x, y, theta)
        return Pose(np.array([x, y]), _wrap(theta))

    def sample(self, step: float) -> tuple[np.ndarray, np.ndarray]:
        """Points ``(n, 2)`` and headings ``(n,)`` every ``step`` metres of arc length or less,
        the start and the end included."""
        if not step > 0:
            raise ValueError("the sampling step must be > 0")
        count = max(1, math.ceil(self.length / step))
        s = np.linspace(0.0, self.length, count + 1)
        points = np.empty((len(s), 2))
        headings = np.empty(len(s))
        x, y, theta = _unpack(self.start)
        begin = 0.0
        for k, (kind, t) in enumerate(zip(self.word, self.segments, strict=True)):
            span = t * self.rho
            mask = (s >= begin) if k == 2 else (s >= begin) & (s < begin + span)
            local = np.minimum(s[mask] - begin, span)
            px, py, ph = _advance_many(kind, local, self.rho, x, y, theta)
            points[mask, 0], points[mask, 1], headings[mask] = px, py, ph
            x, y, theta = _advance(kind, span, self.rho, x, y, theta)
            begin += span
        return points, headings


def dubins_words(start: Pose, goal: Pose, rho: float) -> list[DubinsPath]:
    """Every feasible Dubins word from ``start`` to ``goal`` with turning radius ``rho``,
    shortest first (at most six; LSL and RSR always exist)."""
    if not rho > 0:
        raise ValueError("the turning radius must be > 0")
    x0, y0, theta0 = _unpack(start)
    x1, y1, theta1 = _unpack(goal)
    dx, dy = x1 - x0, y1 - y0
    d = math.hypot(dx, dy) / rho
    phi = math.atan2(dy, dx) if d > 0 else 0.0
    alpha = _mod(theta0 - phi)
    beta = _mod(theta1 - phi)
    found: list[DubinsPath] = []
    for word in WORDS:
        segments = _SOLVERS[word](alpha, beta, d)
        if segments is not None:
            found.append(DubinsPath(start, word, segments, rho))
    found.sort(key=lambda p: p.length)
    return found


def _unpack(pose: Pose) -> tuple[float, float, float]:
    """``(x, y, heading)`` of a planar pose as floats."""
    return float(pose.position[0]), float(pose.position[1]), float(pose.heading)


def _mod(angle: float) -> float:
    """``angle`` in ``[0, 2 pi)``; a hair below ``2 pi`` is 0 (rounding must not add a loop)."""
    wrapped = angle - TWO_PI * math.floor(angle / TWO_PI)
    return 0.0 if wrapped > TWO_PI - 1e-9 else wrapped


def _wrap(angle: float) -> float:
    return (angle + math.pi) % TWO_PI - math.pi


Segments = tuple[float, float, float]


def _lsl(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    p_sq = 2.0 + d * d - 2.0 * math.cos(a - b) + 2.0 * d * (sa - sb)
    if p_sq < 0.0:
        return None
    turn = math.atan2(cb - ca, d + sa - sb)
    return _mod(turn - a), math.sqrt(p_sq), _mod(b - turn)


def _rsr(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    p_sq = 2.0 + d * d - 2.0 * math.cos(a - b) + 2.0 * d * (sb - sa)
    if p_sq < 0.0:
        return None
    turn = math.atan2(ca - cb, d - sa + sb)
    return _mod(a - turn), math.sqrt(p_sq), _mod(turn - b)


def _lsr(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    p_sq = -2.0 + d * d + 2.0 * math.cos(a - b) + 2.0 * d * (sa + sb)
    if p_sq < 0.0:
        return None
    p = math.sqrt(p_sq)
    turn = math.atan2(-ca - cb, d + sa + sb) - math.atan2(-2.0, p)
    return _mod(turn - a), p, _mod(turn - b)


def _rsl(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    p_sq = -2.0 + d * d + 2.0 * math.cos(a - b) - 2.0 * d * (sa + sb)
    if p_sq < 0.0:
        return None
    p = math.sqrt(p_sq)
    turn = math.atan2(ca + cb, d - sa - sb) - math.atan2(2.0, p)
    return _mod(a - turn), p, _mod(b - turn)


def _rlr(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    c = (6.0 - d * d + 2.0 * math.cos(a - b) + 2.0 * d * (sa - sb)) / 8.0
    if abs(c) > 1.0:
        return None
    p = _mod(TWO_PI - math.acos(c))
    t = _mod(a - math.atan2(ca - cb, d - sa + sb) + p / 2.0)
    return t, p, _mod(a - b - t + p)


def _lrl(a: float, b: float, d: float) -> Segments | None:
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    c = (6.0 - d * d + 2.0 * math.cos(a - b) + 2.0 * d * (sb - sa)) / 8.0
    if abs(c) > 1.0:
        return None
    p = _mod(TWO_PI - math.acos(c))
    t = _mod(-a - math.atan2(ca - cb, d + sa - sb) + p / 2.0)
    return t, p, _mod(b - a - t + p)


_SOLVERS = {"LSL": _lsl, "RSR": _rsr, "LSR": _lsr, "RSL": _rsl, "RLR": _rlr, "LRL": _lrl}


def _advance(
    kind: str, s: float, rho: float, x: float, y: float, theta: float
) -> tuple[float, float, float]:
    """The pose ``s`` metres along a segment of type ``kind`` from ``(x, y, theta)``."""
    if kind == "S":
        return x + s * math.cos(theta), y + s * math.sin(theta), theta
    turn = s / rho if kind == "L" else -s / rho
    side = rho if kind == "L" else -rho
    return (
        x + side * (math.sin(theta + turn) - math.sin(theta)),
        y - side * (math.cos(theta + turn) - math.cos(theta)),
        theta + turn,
    )


def _advance_many(
    kind: str, s: np.ndarray, rho: float, x: float, y: float, theta: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_advance` for an array of distances ``s``."""
    if kind == "S":
        return x + s * math.cos(theta), y + s * math.sin(theta), np.full(len(s), theta)
    turn = s / rho if kind == "L" else -s / rho
    side = rho if kind == "L" else -rho
    heading = theta + turn
    return (
        x + side * (np.sin(heading) - math.sin(theta)),
        y - side * (np.cos(heading) - math.cos(theta)),
        heading,
    )
