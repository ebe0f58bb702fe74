"""Keep the lasso at the robot's clearance from the regions its task forbids where it passes.

TL-RRT* keeps the clearance (robot radius plus margin) from obstacles, but regions only by their
labels: rewiring and polishing pull the path tight against a region whose entry the automaton
forbids in the current state (``g2`` before ``g1`` in ``!g2 U g1``). A robot tracking such a
guide with any error enters the region and the task is lost (racecar mission 1009 of
``bench/generality.py``: the guide passed 0.01 m from ``g2``; ``bench/LEARNING.md``).

So, after polishing, the waypoints closer than the clearance to a region forbidden in their
state are pushed away from it, each move kept only if it gains distance and the run stays valid
(collision free, the same automaton states). This is best effort: where the region leaves no
room (a door between two forbidden regions), the path keeps what distance it can.

The same push keeps a plan off the obstacles when it had to be planned with less clearance than
the robot's radius plus its margin (a door too narrow for the whole margin: ``plan_mission``
falls back to half of it, then to the radius alone). Such a plan is valid at the radius, but
TL-RRT* pulls it tight around every corner on its way, where the margin would fit: racecar
mission 1002 of ``bench/generality.py`` (doors of 0.76 and 0.82 m) planned at the radius alone
passed its door posts at 0.3 m and the pursuit controller hit a post at every start. So its
waypoints closer than ``radius + margin`` to an obstacle are pushed out too, before the
regions' push, each move kept only if it gains distance and the run stays valid at the radius.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from planner.geometry.shapes import Shape
from planner.geometry.world import World
from planner.ltl.automaton import Buchi
from planner.search.shortcut import LassoRun, Ops

ROUNDS = 12
"""Push-out passes over the waypoints still too close (each pass may move each one once)."""

OVERSHOOT = 0.05
"""Waypoints are pushed this share beyond the margin, so that the chords between them, which
cut inside a curved region's offset, still keep the margin."""

SAMPLES = 9
"""Points a segment's gap is sampled at, at least."""

SAMPLE_SPACING = 0.25
"""Longest spacing of those points, in margins: a corner between two samples is then missed by
at most 0.8 % of the margin (``hypot(1, 0.125) - 1``). Measured at 9 points whatever their
length, the long chords the thinning makes passed door posts unseen (racecar tuning world 66 of
``bench/generality.py``: 0.34 m from a post, measured no nearer than 0.42 m, for 0.6 m)."""

_MIN_SPACING = 1e-3

_SLACK = 1e-6

Gap = Callable[[np.ndarray, Sequence[int], Sequence[int]], np.ndarray]


def forbidden_regions(
    nba: Buchi, world: World, names: Sequence[str], clearance: float
) -> dict[int, tuple[str, ...]]:
    """Per automaton state, the regions among ``names`` whose entry kills every run there: each
    cube of each guard leaving the state forbids the region, or cannot hold in the world
    together with it. States that forbid nothing are left out."""
    cubes: dict[int, list[tuple[frozenset[str], frozenset[str]]]] = {}
    for edge in nba.edges:
        for cube in edge.guard.sorted_cubes():
            cubes.setdefault(edge.source, []).append((cube.pos, cube.neg))
    out: dict[int, tuple[str, ...]] = {}
    for q, leaving in cubes.items():
        banned = tuple(
            r
            for r in names
            if all(
                r in neg or not world.realisable(pos | {r}, neg, clearance) for pos, neg in leaving
            )
        )
        if banned:
            out[q] = banned
    return out


class RegionGap:
    """The distance of points to the regions forbidden in their automaton states."""

    def __init__(self, world: World, forbidden: dict[int, tuple[str, ...]]) -> None:
        self.shapes: dict[int, list[Shape]] = {
            q: [world.regions[r] for r in names] for q, names in forbidden.items()
        }

    def distance(self, points: np.ndarray, states: Sequence[int]) -> np.ndarray:
        """(n,) distance of each point to the nearest region forbidden in its state (inf: none)."""
        out = np.full(len(points), np.inf)
        for q in set(states):
            shapes = self.shapes.get(q)
            if not shapes:
                continue
            rows = np.flatnonzero(np.asarray(states) == q)
            near = np.min([s.distance(points[rows]) for s in shapes], axis=0)
            out[rows] = np.minimum(out[rows], near)
        return out

    def __call__(
        self, points: np.ndarray, before: Sequence[int], after: Sequence[int]
    ) -> np.ndarray:
        """(n,) distance of each point to the regions forbidden in either of its two states
        (the state it is reached in and the one it leaves in)."""
        return np.minimum(self.distance(points, before), self.distance(points, after))


class ObstacleGap:
    """The distance of points to the obstacles and bounds, in every automaton state."""

    def __init__(self, world: World) -> None:
        self.world = world

    def __call__(
        self, points: np.ndarray, before: Sequence[int], after: Sequence[int]
    ) -> np.ndarray:
        return self.world.obstacle_distance(points)


class KeepOut:
    """Pushes a lasso's waypoints to ``margin`` from what ``gap`` measures the distance to
    (a point reached in state ``before`` and left in state ``after``)."""

    def __init__(self, ops: Ops, gap: Gap, margin: float) -> None:
        self.ops, self.gap, self.margin = ops, gap, margin

    def closest(self, run: LassoRun) -> float:
        """The least ``gap`` of the run's segments (sampled)."""
        return min(self._segment_gaps(x, q).min(initial=np.inf) for x, q in _polylines(run))

    def apply(self, run: LassoRun) -> LassoRun:
        """``run`` with its waypoints pushed out, or ``run`` itself when nothing is too close
        or the pushed run fails the exact re-check."""
        if self.closest(run) >= self.margin - _SLACK:
            return run
        p, pq = self._push(run.prefix, run.prefix_states)
        s, sq = run.suffix, run.suffix_states
        if len(s) > 1:
            s, sq = self._push(s, sq)
        out = replace(run, prefix=p, suffix=s, prefix_states=pq, suffix_states=sq)
        return out if self.ops.valid(out) else run

    def _segment_gaps(self, x: np.ndarray, q: Sequence[int]) -> np.ndarray:
        """(segments,) least ``gap`` of each segment, traversed in its start's state (and
        arriving in its end's), sampled at ``SAMPLES`` points or every ``SAMPLE_SPACING``
        margins, whichever is denser."""
        if len(x) < 2:
            return np.full(0, np.inf)
        a, b = x[:-1], x[1:]
        lengths = np.linalg.norm(b - a, axis=1)
        spacing = max(SAMPLE_SPACING * self.margin, _MIN_SPACING)
        counts = np.maximum(SAMPLES, np.ceil(lengths / spacing).astype(int) + 1)
        segment = np.repeat(np.arange(len(a)), counts)
        firsts = np.cumsum(counts) - counts
        t = (np.arange(int(counts.sum())) - firsts[segment]) / (counts[segment] - 1)
        pts = a[segment] + t[:, None] * (b - a)[segment]
        leave = np.asarray(q[:-1])[segment]
        arrive = np.asarray(q[1:])[segment]
        gaps = self.gap(pts, leave.tolist(), arrive.tolist())
        return np.asarray(np.minimum.reduceat(gaps, firsts))

    def _push(self, x: np.ndarray, q: list[int]) -> tuple[np.ndarray, list[int]]:
        x, q = self._subdivide_near(x, q)
        for _ in range(ROUNDS):
            moved = False
            for parity in (1, 2):
                ks = np.arange(parity, len(x) - 1, 2)
                if ks.size == 0:
                    continue
                moved |= self._push_waypoints(x, q, ks)
            if not moved:
                break
        return self._thin(x, q)

    def _thin(self, x: np.ndarray, q: list[int]) -> tuple[np.ndarray, list[int]]:
        """Drop the waypoints the push made redundant: a shortcut is taken only when it comes
        no closer (by ``gap``) than the margin, or than the path it replaces."""
        gaps = self._segment_gaps(x, q)

        def keeps_out(i: int, j: int) -> bool:
            gap = self._segment_gaps(x[[i, j]], [q[i], q[j]])[0]
            return bool(gap >= min(self.margin, float(gaps[i:j].min())) - _SLACK)

        return self.ops.shortcut(x, q, keeps_out)

    def _subdivide_near(self, x: np.ndarray, q: list[int]) -> tuple[np.ndarray, list[int]]:
        """Split the segments that pass too close into pieces of half the margin, so that
        moving their waypoints moves the whole segment."""
        gaps = self._segment_gaps(x, q)
        out_x, out_q = [x[0]], [q[0]]
        for i in range(1, len(x)):
            if gaps[i - 1] < self.margin:
                piece, piece_q = self.ops.subdivide(
                    x[i - 1 : i + 1], q[i - 1 : i + 1], self.margin / 2
                )
                out_x.extend(piece[1:])
                out_q.extend(piece_q[1:])
            else:
                out_x.append(x[i])
                out_q.append(q[i])
        return np.array(out_x), out_q

    def _push_waypoints(self, x: np.ndarray, q: list[int], ks: np.ndarray) -> bool:
        """Move the waypoints ``ks`` (in place) that are too close, away from the nearest
        thing ``gap`` measures; returns whether any moved."""
        before = [q[k - 1] for k in ks]
        here = [q[k] for k in ks]
        gap = self.gap(x[ks], before, here)
        close = np.flatnonzero(gap < self.margin - _SLACK)
        if close.size == 0:
            return False
        ks, gap = ks[close], gap[close]
        before, here = [before[i] for i in close], [here[i] for i in close]
        away = self._away(x[ks], before, here)
        usable = np.flatnonzero(np.linalg.norm(away, axis=1) > 0)
        moved = False
        todo = np.zeros(ks.size, dtype=bool)
        todo[usable] = True
        for share in (1.0, 0.5, 0.25):
            idx = np.flatnonzero(todo)
            if idx.size == 0:
                break
            k = ks[idx]
            push = share * ((1.0 + OVERSHOOT) * self.margin - gap[idx])
            cand = x[k] + push[:, None] * away[idx]
            b, h = [before[i] for i in idx], [here[i] for i in idx]
            good = self.ops.moves_ok(x[k - 1], cand, x[k + 1], b, h)
            # Only a move that gains distance: between two things (a door's posts) the whole
            # push lands as close to the other one, half of it in the middle.
            good &= self.gap(cand, b, h) > gap[idx] + _SLACK
            x[k[good]] = cand[good]
            todo[idx[good]] = False
            moved |= bool(good.any())
        return moved

    def _away(self, p: np.ndarray, before: list[int], here: list[int]) -> np.ndarray:
        """(n, d) unit directions that increase ``gap`` (central differences; zero where it is
        flat)."""
        h = max(self.margin * 1e-3, 1e-6)
        grad = np.zeros_like(p)
        for j in range(p.shape[1]):
            step = np.zeros(p.shape[1])
            step[j] = h
            grad[:, j] = (self.gap(p + step, before, here) - self.gap(p - step, before, here)) / (
                2 * h
            )
        norm = np.linalg.norm(grad, axis=1, keepdims=True)
        return np.where(norm > 1e-9, grad / np.where(norm > 0, norm, 1.0), 0.0)


def keep_out(
    run: LassoRun, ops: Ops, nba: Buchi, names: Sequence[str], clearance: float, hold: float
) -> LassoRun:
    """``run`` with its waypoints pushed to ``hold`` from the obstacles (when the plan could
    keep only ``clearance`` < ``hold`` everywhere), then to ``clearance`` from the regions
    among ``names`` forbidden in their states; each push is kept only if the run stays valid."""
    world = ops.world
    if hold > clearance + _SLACK:
        run = KeepOut(ops, ObstacleGap(world), hold).apply(run)
    forbidden = forbidden_regions(nba, world, names, clearance)
    if forbidden:
        run = KeepOut(ops, RegionGap(world, forbidden), clearance).apply(run)
    return run


def _polylines(run: LassoRun) -> list[tuple[np.ndarray, list[int]]]:
    return [(run.prefix, run.prefix_states), (run.suffix, run.suffix_states)]
