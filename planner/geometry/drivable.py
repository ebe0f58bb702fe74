"""Drivable guides: a sub-task's polyline redrawn as a path a car can follow.

TL-RRT* plans polylines for a point. A car that only drives forward and turns no tighter than a
radius ``rho`` cannot follow a polyline's corners, least of all where the lasso leaves a region
the way it came in: the mission hands the car over facing into the region and the polyline turns
back on itself. :func:`drivable_path` redraws the polyline from the car's real start pose as a
chain of Dubins paths (:mod:`planner.geometry.dubins`) through waypoints taken along the
polyline (one every ``spacing``, and every corner, each facing along the polyline), choosing by
dynamic programming the shortest chain that ends at the polyline's last point. Each Dubins piece
must keep ``clearance`` from the obstacles and the bounds, and may meet only regions the
polyline (or the start) already meets, so the redrawn path produces no label the plan did not;
keeping a clearance, it keeps what that clearance adds to the last one (the robot's radius)
from the other regions too, so that a car following it does not stray into one. A
U-turn becomes a loop of radius ``rho`` wherever there is room for one; where there is none at
the start, the car first drives off to a pose nearby from which it can join the polyline, and
where it cannot drive off forwards (a wall just ahead, facing away from the polyline), it backs
off first: a three-point turn, whose reversing lead :attr:`DrivablePath.cusp` marks."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from planner.geometry.dubins import DubinsPath, dubins_words
from planner.geometry.pose import Pose
from planner.geometry.world import World

STEP = 0.05
"""Spacing (m) of the points a Dubins piece is checked and drawn with."""

TURN_AROUND_REACH = 6
"""How far (in turning radii, along each axis) from the start a turn-around may lead."""

TURN_AROUND_HEADINGS = 8
"""Headings tried at each turn-around position."""

REVERSE_WEIGHT = 3.0
"""How much longer a metre driven backwards counts than one driven forwards, when turn-arounds
are ranked: a short back-up then a drive forwards, rather than a long reversing loop."""

TURN_AROUND_TRIES = 200
"""Drivable turn-around pieces tried, shortest first, before the redraw gives up."""

TIGHT_COST = 1.0
"""How much more a metre of a piece counts per step down the redraw's clearances: a piece that
keeps less than the full clearance is taken where nothing longer by up to this share keeps it."""


@dataclass(frozen=True)
class DrivablePath:
    """A redrawn path: ``points`` ``(m, 2)`` at most ``STEP`` apart, of which the car drives
    ``points[: cusp + 1]`` backwards (``cusp`` 0: all forwards)."""

    points: np.ndarray
    cusp: int = 0


@dataclass(frozen=True)
class Waypoint:
    """A pose on the polyline and the polyline length before it."""

    pose: Pose
    along: float


def waypoints(path: np.ndarray, spacing: float) -> list[Waypoint]:
    """Poses every ``spacing`` metres or less along ``path`` ``(n, 2)`` and at every vertex,
    facing along the polyline (the bisector of the two segments at an interior vertex, the
    outgoing segment where they cancel). Repeated points are dropped."""
    pts = [np.asarray(path[0], dtype=float)]
    for p in np.asarray(path[1:], dtype=float):
        if float(np.hypot(*(p - pts[-1]))) > 1e-9:
            pts.append(p)
    if len(pts) < 2:
        return [Waypoint(Pose(pts[0], 0.0), 0.0)]
    units = [(b - a) / float(np.hypot(*(b - a))) for a, b in itertools.pairwise(pts)]
    out: list[Waypoint] = []
    along = 0.0
    for k, (a, b) in enumerate(itertools.pairwise(pts)):
        length = float(np.hypot(*(b - a)))
        heading = math.atan2(float(units[k][1]), float(units[k][0]))
        if k == 0:
            out.append(Waypoint(Pose(a, heading), 0.0))
        pieces = max(1, math.ceil(length / spacing - 1e-9))
        for i in range(1, pieces):
            p = a + (b - a) * (i / pieces)
            pose = Pose(p, heading)
            out.append(Waypoint(pose, along + length * i / pieces))
        along += length
        if k + 1 < len(units):
            mean = units[k] + units[k + 1]
            if float(np.hypot(*mean)) < 1e-9:
                mean = units[k + 1]
            heading = math.atan2(float(mean[1]), float(mean[0]))
        out.append(Waypoint(Pose(b, heading), along))
    return out


class _Checker:
    """Whether a Dubins piece keeps ``clearance`` from obstacles and bounds and meets only
    allowed regions, keeping ``region_margin`` from the others."""

    def __init__(
        self, world: World, clearance: float, allowed: np.ndarray, region_margin: float = 0.0
    ) -> None:
        self.world, self.clearance, self.forbidden = world, clearance, ~allowed
        self.region_margin = region_margin

    def points(self, piece: DubinsPath) -> np.ndarray | None:
        """The piece's points when it is drivable, else None."""
        pts, _ = piece.sample(STEP)
        return pts if self.clear(pts) and self.allowed(pts) else None

    def clear(self, pts: np.ndarray) -> bool:
        """Whether the polyline ``pts`` keeps the clearance from obstacles and bounds."""
        return bool(np.all(self.world.segments_free(pts[:-1], pts[1:], self.clearance)))

    def allowed(self, pts: np.ndarray) -> bool:
        """Whether ``pts`` meet only allowed regions, ``region_margin`` off the others."""
        if not self.forbidden.any():
            return True
        met = self.world.label_matrix(pts, self.region_margin)
        return not np.any(met[:, self.forbidden])


def allowed_regions(world: World, path: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``(len(region_names),)`` the regions the polyline or the start point meets."""
    pts = [np.asarray(start, dtype=float)[None, :]]
    for a, b in itertools.pairwise(np.asarray(path, dtype=float)):
        count = max(1, math.ceil(float(np.hypot(*(b - a))) / (STEP / 2)))
        pts.append(a + (b - a) * np.linspace(0.0, 1.0, count + 1)[:, None])
    return np.asarray(world.label_matrix(np.vstack(pts)).any(axis=0))


def drivable_path(
    world: World,
    path: np.ndarray,
    start: Pose,
    rho: float,
    clearance: float,
    *,
    fallback: Sequence[float] = (),
    spacing: float | None = None,
    reach: float | None = None,
) -> DrivablePath | None:
    """``path`` ``(n, 2)`` redrawn from ``start`` as Dubins pieces of turning radius ``rho``
    (see the module docstring): points at most ``STEP`` apart from the start's position to
    ``path[-1]``, or None when no such chain keeps ``clearance``.

    ``fallback``: smaller clearances, largest first, that a piece may keep where none keeps
    ``clearance`` (each step down costs ``TIGHT_COST`` times the piece's length more), so that
    one tight spot, such as a turn-around at the start, does not bring the whole path down to
    its clearance. A piece keeps a clearance only if it also keeps what that adds to the last
    one from the regions it may not meet. ``spacing`` (default ``rho``) is the waypoint spacing
    along the polyline and ``reach`` (default ``6 rho``) the longest stretch of polyline one
    piece may replace."""
    if world.dim != 2:
        raise ValueError("drivable paths are planar: the world must be 2D")
    levels = [clearance, *fallback]
    if not rho > 0 or not all(c >= 0 for c in levels):
        raise ValueError("the turning radius must be > 0 and the clearances >= 0")
    poly = np.asarray(path, dtype=float)
    nodes = waypoints(poly, spacing or rho)
    span = reach if reach is not None else 6.0 * rho
    allowed = allowed_regions(world, poly, np.asarray(start.position, dtype=float))
    checkers = [_Checker(world, c, allowed, c - levels[-1]) for c in levels]
    count = len(nodes)
    cost = [math.inf] * count
    parent = [-2] * count
    pieces: list[np.ndarray | None] = [None] * count
    cusps = [0] * count

    def relax(source: int, origin: Pose, base: float, lo: float, lead: Lead | None = None) -> None:
        for j in range(count):
            if nodes[j].along < lo or nodes[j].along > lo + span:
                continue
            if j <= source:
                continue
            for piece in dubins_words(origin, nodes[j].pose, rho):
                if base + piece.length >= cost[j]:
                    break
                found = _drawn(checkers, piece)
                if found is None:
                    continue
                pts, level = found
                total = base + piece.length * (1.0 + TIGHT_COST * level)
                if total < cost[j]:
                    joined = pts if lead is None else np.vstack([lead.points, pts[1:]])
                    cost[j], parent[j], pieces[j] = total, source, joined
                    cusps[j] = 0 if lead is None else lead.cusp
                if level == 0:
                    break  # a longer word can only cost more

    relax(-1, start, 0.0, 0.0)
    join = next((n for n in nodes if n.along >= 2.0 * rho), nodes[-1]).pose
    for level, checker in enumerate(checkers):  # no piece joins the start: turn round first
        if any(math.isfinite(c) for c in cost):
            break
        for backwards in (False, True):
            if any(math.isfinite(c) for c in cost):
                break
            for lead in _turn_arounds(checker, start, join, rho, backwards):
                relax(-1, lead.end, lead.cost * (1.0 + TIGHT_COST * level), 0.0, lead)
                if not backwards and any(math.isfinite(c) for c in cost):
                    break  # backing up, every lead is tried: the cheapest chain wins
    for i in range(count):
        if math.isfinite(cost[i]):
            relax(i, nodes[i].pose, cost[i], nodes[i].along, None)
    end = count - 1
    if not math.isfinite(cost[end]):
        return None
    chain: list[np.ndarray] = []
    j = end
    while j >= 0:
        piece = pieces[j]
        assert piece is not None
        chain.append(piece)
        first, j = j, parent[j]
    chain.reverse()
    return DrivablePath(np.vstack([chain[0], *(c[1:] for c in chain[1:])]), cusps[first])


def _drawn(checkers: Sequence[_Checker], piece: DubinsPath) -> tuple[np.ndarray, int] | None:
    """The piece's points and the first of ``checkers`` (one world, regions and clearances
    largest first) whose clearances it keeps (None: none, or a forbidden region)."""
    pts, _ = piece.sample(STEP)
    if not checkers[-1].allowed(pts):
        return None
    level = next((k for k, c in enumerate(checkers) if c.allowed(pts) and c.clear(pts)), None)
    return None if level is None else (pts, level)


def _backwards(pose: Pose) -> Pose:
    """The pose facing the other way: a Dubins piece between two such poses is driven in
    reverse between the originals."""
    return Pose(pose.position, pose.heading + math.pi)


@dataclass(frozen=True)
class Lead:
    """A turn-around piece: its ``points``, the pose it ends in, its ``cost`` (its length,
    ``REVERSE_WEIGHT`` times it backing up) and ``cusp`` (its last point's index backing up,
    else 0)."""

    points: np.ndarray
    end: Pose
    cost: float
    cusp: int


def _turn_arounds(
    checker: _Checker, start: Pose, join: Pose, rho: float, backwards: bool = False
) -> Iterator[Lead]:
    """Drivable Dubins pieces from ``start`` to poses around it, those from which ``join``
    looks nearest first: where no piece joins the start to the polyline (the car faces away
    with no room for a loop on the spot), it may first drive off (``backwards``: back off) to
    where it can turn. Poses lie on a grid ``rho`` apart within ``TURN_AROUND_REACH`` turning
    radii, ``TURN_AROUND_HEADINGS`` headings each; at most ``TURN_AROUND_TRIES`` drivable ones
    are offered."""
    steps = np.arange(-TURN_AROUND_REACH, TURN_AROUND_REACH + 1) * rho
    centre = np.asarray(start.position, dtype=float)
    headings = np.arange(TURN_AROUND_HEADINGS) * (2 * math.pi / TURN_AROUND_HEADINGS)
    weight = REVERSE_WEIGHT if backwards else 1.0
    candidates: list[tuple[float, int, list[DubinsPath]]] = []
    for dx, dy in itertools.product(steps, steps):
        position = centre + np.array([dx, dy])
        if checker.world.in_collision(position[None, :], checker.clearance)[0]:
            continue
        for heading in headings:
            pose = Pose(position, float(heading))
            if backwards:
                words = dubins_words(_backwards(start), _backwards(pose), rho)
            else:
                words = dubins_words(start, pose, rho)
            onward = dubins_words(pose, join, rho)
            if words and onward:
                cost = weight * words[0].length + onward[0].length
                candidates.append((cost, len(candidates), words))
    candidates.sort(key=lambda c: (c[0], c[1]))
    tries = 0
    for _, _, words in candidates:
        for word in words:
            pts = checker.points(word)
            if pts is not None:
                end, cusp = (_backwards(word.end()), len(pts) - 1) if backwards else (word.end(), 0)
                yield Lead(pts, end, weight * word.length, cusp)
                tries += 1
                break
        if tries >= TURN_AROUND_TRIES:
            return


def thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points of the dense path ``points`` every ``spacing`` metres of arc length (the first
    and the last kept): the waypoints of a guide whose balls sit ``spacing`` apart."""
    if not spacing > 0:
        raise ValueError("the spacing must be > 0")
    pts = np.asarray(points, dtype=float)
    along = arc_lengths(pts)
    count = max(1, math.ceil(along[-1] / spacing - 1e-9))
    marks = np.linspace(0.0, along[-1], count + 1)
    return np.stack([np.interp(marks, along, pts[:, j]) for j in range(pts.shape[1])], axis=1)


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """``(n,)`` length of the polyline ``points`` ``(n, d)`` from its first point to each."""
    steps = np.linalg.norm(np.diff(np.asarray(points, dtype=float), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])
