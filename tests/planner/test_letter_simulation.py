"""The letter simulation (bit arrays) against the cube simulation (worklist), which
decides the same relation by another algorithm, and on automata whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from planner.ltl.families import FAMILIES, PATTERNS
from planner.ltl.formula import parse, to_nnf
from planner.ltl.gba import Degeneralizer, RawBuchi
from planner.ltl.guard import Cube
from planner.ltl.letter_simulation import letter_simulation
from planner.ltl.reduce import LETTER_ATOMS, cube_simulation, merge_identical
from planner.ltl.rewrite import simplify
from planner.ltl.trim import trim
from planner.ltl.vwaa import build_vwaa

CORPUS = [
    *(text for texts in PATTERNS.values() for text in texts),
    *(FAMILIES["response-chain"](k) for k in range(1, 7)),
    *(FAMILIES["gf-and"](k) for k in range(1, 7)),
    *(FAMILIES["gh-r"](k) for k in range(1, 5)),
    *(FAMILIES["rv-counter"](k) for k in range(1, 3)),
    "[]!o && <>(a && <>(b && <>c))",
    "[]<>a && []<>b && [](a -> <>c) && []!o",
]


def _unreduced(text: str) -> RawBuchi:
    return trim(
        merge_identical(trim(Degeneralizer(build_vwaa(simplify(to_nnf(parse(text))))).build()))
    )


def _atoms(ba: RawBuchi) -> list[str]:
    return sorted(
        {a for out in ba.edges.values() for cs in out.values() for c in cs for a in c.atoms}
    )


def _as_sets(sim: np.ndarray) -> list[set[int]]:
    return [set(np.flatnonzero(row).tolist()) for row in sim]


def test_the_letter_and_the_cube_simulation_agree_on_every_automaton_of_the_corpus() -> None:
    compared = 0
    for text in CORPUS:
        ba = _unreduced(text)
        names = _atoms(ba)
        if len(names) > LETTER_ATOMS:
            continue
        assert _as_sets(letter_simulation(ba, names)) == cube_simulation(ba), text
        compared += 1
    assert compared >= 110


def _cube(pos: str = "", neg: str = "") -> Cube:
    return Cube(frozenset(pos.split()), frozenset(neg.split()))


def test_more_transitions_simulate_fewer_and_acceptance_must_be_matched() -> None:
    # 0 -a-> 2, 1 -a,b-> 2: 1 simulates 0, not back. 2 accepts and loops on every letter, so
    # it simulates all; 3 loops the same way without accepting, so it simulates only itself
    # (0 and 1 must answer into a simulator of the accepting 2).
    true = _cube()
    ba = RawBuchi(
        initial=0,
        accepting={2},
        edges={
            0: {2: [_cube("a")]},
            1: {2: [_cube("a"), _cube("b")]},
            2: {2: [true]},
            3: {3: [true]},
        },
        names=["0", "1", "2", "3"],
    )
    sim = _as_sets(letter_simulation(ba, ["a", "b"]))
    assert sim[0] == {0, 1, 2}
    assert sim[1] == {1, 2}
    assert sim[2] == {2}
    assert sim[3] == {2, 3}
    assert sim == cube_simulation(ba)


@pytest.mark.parametrize("atoms", [1, 6, 7, 8])
def test_letters_of_every_word_size_are_read(atoms: int) -> None:
    # One state answers only the letter where every atom holds: the last bit of the
    # last 64-bit word when there are 7 or 8 atoms.
    names = [f"p{i}" for i in range(atoms)]
    everything = Cube(frozenset(names), frozenset())
    ba = RawBuchi(
        initial=0,
        accepting={0, 1},
        edges={0: {0: [everything]}, 1: {1: [Cube(frozenset(names[:-1]), frozenset())]}},
        names=["0", "1"],
    )
    sim = _as_sets(letter_simulation(ba, names))
    assert sim == [{0, 1}, {1}]
