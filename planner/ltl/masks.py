"""Cubes as bit masks: the degeneralization's inner loop.

A cube is a pair of ints, the bits of its positive and of its negative atoms (the
degeneralizer numbers the atoms). The functions mirror :func:`planner.ltl.gba.add_cube` and
:func:`planner.ltl.guard.covers` on that form.
"""

from __future__ import annotations

from planner.ltl.guard import Cube

Mask = tuple[int, int]


def add_mask(masks: list[Mask], pos: int, neg: int) -> None:
    """Add the cube ``(pos, neg)`` to the disjunction ``masks``, keeping no cube that implies
    another (a cube implies another when its bit sets contain the other's)."""
    implied_by_new = False
    for other_pos, other_neg in masks:
        if other_pos & pos == other_pos and other_neg & neg == other_neg:
            return
        if pos & other_pos == pos and neg & other_neg == neg:
            implied_by_new = True
    if implied_by_new:
        if len(masks) == 1:  # the usual case: a weaker cube replaces the one there
            masks[0] = (pos, neg)
            return
        masks[:] = [(p, n) for p, n in masks if not (pos & p == pos and neg & n == neg)]
    masks.append((pos, neg))


def masks_cover(masks: list[Mask], pos: int, neg: int) -> bool:
    """Whether the disjunction ``masks`` holds on every letter satisfying ``(pos, neg)``."""
    rest = []
    for other_pos, other_neg in masks:
        if other_pos & neg or other_neg & pos:
            continue
        other_pos &= ~pos
        other_neg &= ~neg
        if not other_pos | other_neg:
            return True
        rest.append((other_pos, other_neg))
    if not rest:
        return False
    first_pos, first_neg = rest[0]
    atoms = first_pos | first_neg
    atom = atoms & -atoms
    return masks_cover(rest, atom, 0) and masks_cover(rest, 0, atom)


class CubeOf(dict[Mask, Cube]):
    """The cube of each mask, made once (the masks' bits are those of ``atom_bits``)."""

    def __init__(self, atom_bits: dict[str, int]) -> None:
        super().__init__()
        self.atom_bits = atom_bits
        self._atoms: dict[int, frozenset[str]] = {}

    def __missing__(self, mask: Mask) -> Cube:
        pos, neg = mask
        cube = self[mask] = Cube(self._atoms_of(pos), self._atoms_of(neg))
        return cube

    def _atoms_of(self, bits: int) -> frozenset[str]:
        atoms = self._atoms.get(bits)
        if atoms is None:
            atoms = self._atoms[bits] = frozenset(a for a, b in self.atom_bits.items() if b & bits)
        return atoms
