"""Cut a lasso into reach-avoid sub-tasks, one per automaton-constant piece.

The lasso is cut at every waypoint where the automaton state changes and at the end of each
phase. A piece runs from the previous cut point to the next one; its goal is the region whose
entry made the automaton move:

* the candidate labels are the positive literals of the cubes of the transition
  ``q -> q'`` that hold at the cut point; among them a region *entered* there (absent at the
  previous waypoint) wins, then any region containing the cut point (sorted by name, so the
  choice is deterministic when one label set holds several regions);
* a piece that ends the phase without a state change (the prefix may run on inside the
  accepting state) gets the region containing its end point, preferring one just entered;
* a transition taken on *leaving* a region (a guard with negative literals only) has no region
  to reach: its piece is merged into the following piece of the same phase, whose goal then
  applies. Only when such a piece ends its phase does it keep the empty goal ``""``, meaning
  "reach the end of the guide path" (the cut point); every other sub-task path ends inside its
  goal region.

Zero-length pieces are merged into their successor. Prefix sub-tasks come first, then suffix
sub-tasks; the suffix starts at the accepting state and point where the prefix ended.
``split_into_legs`` cuts long sub-tasks into legs (``planner.leg_length``): every leg but the
last has the empty goal and ends in the last r-ball of its guide.

A rollout of the mission drives them in *lasso order* (:func:`lasso_stages`): the prefix
sub-tasks once, then the suffix sub-tasks over and over; the sub-task driven at each stage is
:func:`subtask_at`. Training, hand-overs, evaluation and the bundled policy all follow it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from planner.geometry.world import World

if TYPE_CHECKING:
    from planner.ltl.automaton import Buchi
    from planner.search.tl_rrt_star import Lasso

Phase = Literal["prefix", "suffix"]


@dataclass
class SubTask:
    """Reach region ``goal`` from ``start`` along the guide ``path`` (``path[0] == start``,
    ``path[-1]`` in the goal region), never touching obstacles. ``nba_state`` is the
    automaton state during the piece and ``next_nba_state`` the one entered at its end. A car's
    redrawn guide (``envs.drivable``) is driven backwards over ``path[: reverse + 1]``."""

    index: int
    phase: Phase
    goal: str
    start: np.ndarray
    path: np.ndarray
    nba_state: int
    next_nba_state: int
    reverse: int = 0


@dataclass
class _Piece:
    lo: int
    hi: int
    goal: str
    q_from: int
    q_to: int


def _regions(world: World, x: np.ndarray) -> frozenset[str]:
    return world.labels(x) - {World.OBSTACLE}


def _goal(
    nba: Buchi,
    here: frozenset[str],
    before: frozenset[str],
    q_from: int,
    q_to: int,
) -> str:
    entered = here - before
    enabling: set[str] = set()
    if q_from != q_to:
        for edge in nba.out_edges(q_from):
            if edge.target == q_to:
                for cube in edge.guard.sorted_cubes():
                    if cube.holds(here):
                        enabling |= cube.pos
        for pool in (enabling & entered, enabling & here):
            if pool:
                return sorted(pool)[0]
        if not enabling:
            # A transition taken on leaving a region: no region to reach here.
            return ""
    for region_pool in (entered, here):
        if region_pool:
            return sorted(region_pool)[0]
    return ""


def _pieces(nba: Buchi, world: World, points: np.ndarray, states: list[int]) -> list[_Piece]:
    n = len(points) - 1
    if n < 1:
        return []
    labels = [_regions(world, x) for x in points]
    cuts = [k for k in range(1, n + 1) if states[k] != states[k - 1] or k == n]
    pieces: list[_Piece] = []
    lo = 0
    for k in cuts:
        q_from, q_to = states[lo], states[k]
        goal = _goal(nba, labels[k], labels[k - 1], states[k - 1], q_to)
        pieces.append(_Piece(lo, k, goal, q_from, q_to))
        lo = k
    merged: list[_Piece] = []
    carry: _Piece | None = None
    for i, piece in enumerate(pieces):
        if carry is not None:
            piece = _Piece(carry.lo, piece.hi, piece.goal, carry.q_from, piece.q_to)
            carry = None
        degenerate = not np.any(points[piece.lo + 1 : piece.hi + 1] != points[piece.lo])
        if (piece.goal == "" or degenerate) and i < len(pieces) - 1:
            carry = piece
            continue
        if degenerate and merged:
            last = merged[-1]
            merged[-1] = _Piece(last.lo, piece.hi, last.goal, last.q_from, piece.q_to)
            continue
        if not degenerate:
            merged.append(piece)
    return merged


def decompose(lasso: Lasso, nba: Buchi, world: World) -> list[SubTask]:
    """Sub-tasks of ``lasso`` (see the module docstring); ``nba`` is the automaton whose
    states ``lasso.*_states`` refer to (the pruned one TL-RRT* planned with)."""
    out: list[SubTask] = []
    phases: tuple[tuple[Phase, np.ndarray, list[int]], ...] = (
        ("prefix", lasso.prefix, lasso.prefix_states),
        ("suffix", lasso.suffix, lasso.suffix_states),
    )
    for phase, points, states in phases:
        for piece in _pieces(nba, world, np.asarray(points, dtype=float), states):
            path = np.array(points[piece.lo : piece.hi + 1], dtype=float)
            out.append(
                SubTask(
                    index=len(out),
                    phase=phase,
                    goal=piece.goal,
                    start=path[0].copy(),
                    path=path,
                    nba_state=piece.q_from,
                    next_nba_state=piece.q_to,
                )
            )
    return out


def split_subtask(subtask: SubTask, max_length: float) -> list[SubTask]:
    """``subtask`` cut into consecutive pieces of equal path length, at most ``max_length``
    metres each (legs of a long guide, one agent each). Every piece but the last has no goal
    region (``goal == ""``: its episode succeeds in the last r-ball of its path) and stays in
    the sub-task's automaton state; the last piece keeps the goal and the transition. Indices
    are left as they are (``split_into_legs`` renumbers them)."""
    if not max_length > 0:
        raise ValueError(f"max_length must be > 0, got {max_length}")
    path = np.asarray(subtask.path, dtype=float)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    count = max(1, math.ceil(cum[-1] / max_length - 1e-9))
    if count == 1:
        return [subtask]
    cuts = np.linspace(0.0, cum[-1], count + 1)
    inner = [np.interp(cuts[1:-1], cum, path[:, j]) for j in range(path.shape[1])]
    knots = [path[0], *np.stack(inner, axis=1), path[-1]]
    pieces: list[SubTask] = []
    for k in range(count):
        between = path[(cum > cuts[k]) & (cum < cuts[k + 1])]
        piece = np.vstack([knots[k], between, knots[k + 1]])
        last = k == count - 1
        pieces.append(
            dataclasses.replace(
                subtask,
                start=piece[0].copy(),
                path=piece,
                goal=subtask.goal if last else "",
                next_nba_state=subtask.next_nba_state if last else subtask.nba_state,
            )
        )
    return pieces


def split_into_legs(subtasks: Sequence[SubTask], max_length: float) -> list[SubTask]:
    """``subtasks`` with every one whose path is longer than ``max_length`` cut into legs
    (``split_subtask``), in order and numbered anew."""
    legs = [leg for sub in subtasks for leg in split_subtask(sub, max_length)]
    return [dataclasses.replace(leg, index=k) for k, leg in enumerate(legs)]


def phases(subtasks: Sequence[SubTask]) -> tuple[list[int], list[int]]:
    """Positions in ``subtasks`` of the prefix sub-tasks and of the suffix sub-tasks."""
    prefix = [i for i, s in enumerate(subtasks) if s.phase == "prefix"]
    suffix = [i for i, s in enumerate(subtasks) if s.phase == "suffix"]
    return prefix, suffix


def lasso_stages(subtasks: Sequence[SubTask], cycles: int) -> list[int]:
    """Positions in ``subtasks`` of the stages of a rollout: the prefix sub-tasks once, then
    the suffix sub-tasks ``cycles`` times."""
    prefix, suffix = phases(subtasks)
    return prefix + suffix * cycles


def subtask_at(subtasks: Sequence[SubTask], stage: int) -> int:
    """Position in ``subtasks`` of the sub-task that acts at ``stage`` of an endless rollout
    (the suffix repeats forever; a finite task stays with its last sub-task)."""
    prefix, suffix = phases(subtasks)
    if stage < len(prefix) or not suffix:
        return prefix[min(stage, len(prefix) - 1)]
    return suffix[(stage - len(prefix)) % len(suffix)]
