"""Cubes as bit masks agree with the cube functions they stand in for."""

from __future__ import annotations

import random

from planner.ltl.gba import add_cube
from planner.ltl.guard import Cube, covers
from planner.ltl.masks import Mask, add_mask, masks_cover

ATOMS = ("a", "b", "c", "d")


def random_cube(rng: random.Random) -> Cube:
    pos: set[str] = set()
    neg: set[str] = set()
    for atom in ATOMS:
        side = rng.randrange(3)
        if side == 1:
            pos.add(atom)
        elif side == 2:
            neg.add(atom)
    return Cube(frozenset(pos), frozenset(neg))


def mask(cube: Cube) -> Mask:
    def bits(atoms: frozenset[str]) -> int:
        return sum(1 << ATOMS.index(a) for a in atoms)

    return bits(cube.pos), bits(cube.neg)


def test_add_mask_keeps_the_cubes_add_cube_keeps() -> None:
    rng = random.Random(7)
    for _ in range(500):
        cubes: list[Cube] = []
        masks: list[Mask] = []
        for _ in range(rng.randrange(1, 8)):
            cube = random_cube(rng)
            add_cube(cubes, cube)
            add_mask(masks, *mask(cube))
        assert sorted(masks) == sorted(mask(c) for c in cubes)


def test_masks_cover_answers_as_covers() -> None:
    rng = random.Random(11)
    answers = set()
    for _ in range(2000):
        cubes = [random_cube(rng) for _ in range(rng.randrange(0, 7))]
        cube = random_cube(rng)
        expected = covers(cubes, cube)
        assert masks_cover([mask(c) for c in cubes], *mask(cube)) == expected, (cubes, cube)
        answers.add(expected)
    assert answers == {True, False}
