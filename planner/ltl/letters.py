"""Sets of letters as bit masks: exact and fast guard algebra over a few atoms.

With ``m`` atoms there are ``2^m`` letters; a set of letters is an integer whose bit ``L``
says whether letter ``L`` (bit ``i`` of ``L``: atom ``i`` holds) is in it. Union,
intersection and inclusion are then single integer operations, which the simulation
computation of :mod:`planner.ltl.reduce` does millions of times; cubes and DNF guards
stay the representation everywhere else (they do not grow with the atoms).
"""

from __future__ import annotations

from planner.ltl.guard import Cube

MAX_ATOMS = 12
"""Above this many atoms a letter set would be a 2^m-bit integer too large to be cheap."""


class LetterSets:
    """The letter-set masks of cubes over the atoms ``names`` (at most :data:`MAX_ATOMS`)."""

    def __init__(self, names: list[str]) -> None:
        if len(names) > MAX_ATOMS:
            raise ValueError(f"{len(names)} atoms: letter sets are for at most {MAX_ATOMS}")
        letters = 1 << len(names)
        self.everything = (1 << letters) - 1
        self._holds: dict[str, int] = {}
        for i, name in enumerate(names):
            self._holds[name] = sum(1 << w for w in range(letters) if w >> i & 1)
        self._cache: dict[Cube, int] = {}

    def of_cube(self, cube: Cube) -> int:
        """The letters that satisfy ``cube``."""
        mask = self._cache.get(cube)
        if mask is None:
            mask = self.everything
            for a in cube.pos:
                mask &= self._holds[a]
            for a in cube.neg:
                mask &= ~self._holds[a]
            self._cache[cube] = mask
        return mask

    def of_cubes(self, cubes: list[Cube]) -> int:
        """The letters that satisfy the disjunction ``cubes``."""
        mask = 0
        for cube in cubes:
            mask |= self.of_cube(cube)
        return mask
