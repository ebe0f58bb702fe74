"""Which product edges exist: the geometric test of a segment (collision free with the
clearance, at most one change of the task label) and the automaton's successor relation per
label (:class:`TransitionTable`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from planner.geometry.labels import LabelOracle
from planner.geometry.world import World

Successors = Callable[[int, int], tuple[int, ...]]
"""The automaton states that follow state ``q`` under the label (bitmask) ``mask``."""


def edges_ok(
    world: World, oracle: LabelOracle, clearance: float, a: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """(n,) validity of product edges' geometry a[i]-b[i]: collision free with the clearance
    and at most one change of the task label along the segment."""
    ok = np.asarray(world.segments_free(a, b, clearance), dtype=bool).copy()
    idx = np.flatnonzero(ok)
    if idx.size:
        ok[idx] = oracle.changes(a[idx], b[idx]) <= 1
    return ok


class TransitionTable:
    """The automaton's successor relation as boolean matrices, one per label met so far.

    Labels (bitmasks) get small ids in order of appearance; ``reach[lid][q, q2]`` tells whether
    ``q2`` is a successor of ``q`` under label ``lid``. Indexing ``reach`` by the label ids of k
    points gives the (k, Q, Q) relation of a whole neighbourhood in one operation.
    ``after[lid][q]`` lists the same successors, ascending, for loops over a few states.
    """

    def __init__(self, successors: Successors, num_states: int) -> None:
        self.successors = successors
        self.num_states = num_states
        self.reach = np.zeros((8, num_states, num_states), dtype=bool)
        self.after: list[list[list[int]]] = []
        self._ids: dict[int, int] = {}

    def label_id(self, mask: int) -> int:
        """The id of label ``mask``, its matrix computed on first sight."""
        lid = self._ids.get(mask)
        if lid is None:
            lid = len(self._ids)
            if lid == len(self.reach):
                self.reach = np.concatenate([self.reach, np.zeros_like(self.reach)])
            after = [sorted(self.successors(q, mask)) for q in range(self.num_states)]
            for q, targets in enumerate(after):
                self.reach[lid, q, targets] = True
            self.after.append(after)
            self._ids[mask] = lid
        return lid
