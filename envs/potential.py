"""The continuous guide distance-to-go that ``EnvOptions.dense_progress`` pays the change of.

From a point ``x`` with progress index ``i`` on a leg: ``D_min`` of the next ball ``i + 1`` plus
the distance from ``x`` to that ball's centre, plus the guide length of the legs after this one
(0 from the leg's last ball on, but for those legs). It is a potential: a step's gain is its
decrease, so the gains of a trip that comes back to where it started add up to nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class GuidePotential:
    """``value(leg, index, x)`` for the legs of one course, from each leg's ball centres,
    their distance-to-go and the guide length after the leg."""

    def __init__(
        self, centres: Sequence[np.ndarray], dist_to_go: Sequence[np.ndarray], rest: Sequence[float]
    ) -> None:
        self._centres = [[tuple(c) for c in np.asarray(cs).tolist()] for cs in centres]
        self._togo = [[float(v) for v in d] for d in dist_to_go]
        self._rest = [float(r) for r in rest]

    def value(self, leg: int, index: int, x: Sequence[float]) -> float:
        """The potential at ``x`` on leg ``leg`` with local progress index ``index`` (-1: no
        ball reached yet)."""
        after = index + 1
        centres = self._centres[leg]
        if after >= len(centres):
            return self._rest[leg]
        return self._rest[leg] + self._togo[leg][after] + math.dist(x, centres[after])
