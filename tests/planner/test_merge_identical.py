"""The merge of identical states against a plain partition refinement on random automata
with copies of states whose guards are written differently."""

from __future__ import annotations

import random

from planner.ltl.gba import RawBuchi
from planner.ltl.guard import Cube
from planner.ltl.reduce import merge_identical, quotient
from tests.planner.test_masks import random_cube


def maximal(cubes: list[Cube]) -> frozenset[Cube]:
    """The cubes that no other cube of ``cubes`` implies: the joined guard's cubes."""
    unique = set(cubes)
    return frozenset(c for c in unique if not any(o != c and c.implies(o) for o in unique))


def reference_classes(ba: RawBuchi) -> list[int]:
    """The coarsest partition by acceptance and joined guards to each class, refined from
    acceptance alone until no class splits (the definition, without shortcuts)."""
    n = ba.num_states
    block = [int(p in ba.accepting) for p in range(n)]
    while True:
        signatures: dict[object, int] = {}
        new_block = []
        for p in range(n):
            joined: dict[int, list[Cube]] = {}
            for target, cubes in ba.edges.get(p, {}).items():
                joined.setdefault(block[target], []).extend(cubes)
            sig = (block[p], frozenset((b, maximal(cs)) for b, cs in joined.items()))
            new_block.append(signatures.setdefault(sig, len(signatures)))
        if len(signatures) == len(set(block)):
            return new_block
        block = new_block


def stronger(rng: random.Random, cube: Cube) -> Cube:
    """``cube`` with one more literal when one is free (a cube that implies it)."""
    free = [a for a in ("a", "b", "c", "d") if a not in cube.pos | cube.neg]
    if not free:
        return cube
    extra = frozenset({rng.choice(free)})
    return (
        Cube(cube.pos | extra, cube.neg) if rng.random() < 0.5 else Cube(cube.pos, cube.neg | extra)
    )


def random_automaton_with_copies(rng: random.Random) -> RawBuchi:
    """Random states, then copies of some of them (and of copies) that send each cube of the
    original to its target or to a copy of it, some with a stronger cube beside it (which
    joining the guards absorbs). Each edge's cubes are irredundant, as the translator's."""
    n = rng.randrange(2, 8)
    accepting = {p for p in range(n) if rng.random() < 0.4}
    edges: dict[int, dict[int, list[Cube]]] = {}
    for p in range(n):
        edges[p] = {}
        for t in rng.sample(range(n), rng.randrange(1, n + 1)):
            cubes = list({random_cube(rng) for _ in range(rng.randrange(1, 4))})
            edges[p][t] = maximal_list(cubes)
    copy_of: dict[int, int] = {}
    for _ in range(rng.randrange(1, 6)):
        original = rng.randrange(len(edges))
        copy = len(edges)
        copy_of[copy] = original
        if original in accepting:
            accepting.add(copy)
        out: dict[int, list[Cube]] = {}
        for t, cubes in edges[original].items():
            twins = [t, *(c for c, o in copy_of.items() if o == t)]
            for cube in cubes:
                out.setdefault(rng.choice(twins), []).append(cube)
                if rng.random() < 0.5:
                    out.setdefault(rng.choice(twins), []).append(stronger(rng, cube))
        if rng.random() < 0.3:  # a copy that differs: one more transition
            out.setdefault(rng.randrange(n), []).append(random_cube(rng))
        edges[copy] = {t: maximal_list(cubes) for t, cubes in out.items()}
    names = [f"q{p}" for p in range(len(edges))]
    return RawBuchi(0, accepting, edges, names)


def maximal_list(cubes: list[Cube]) -> list[Cube]:
    return sorted(maximal(cubes), key=Cube.sort_key)


def as_sets(ba: RawBuchi) -> dict[int, dict[int, frozenset[Cube]]]:
    return {p: {t: frozenset(cs) for t, cs in out.items()} for p, out in ba.edges.items()}


def test_merge_identical_finds_the_coarsest_partition_of_identical_states() -> None:
    rng = random.Random(3)
    merged_some = 0
    for _ in range(400):
        ba = random_automaton_with_copies(rng)
        classes = reference_classes(ba)
        members: dict[int, set[int]] = {}
        for p, c in enumerate(classes):
            members.setdefault(c, set()).add(p)
        expected = quotient(ba, [members[c] for c in classes])
        merged = merge_identical(ba)
        assert as_sets(merged) == as_sets(expected)
        assert (merged.initial, merged.accepting) == (expected.initial, expected.accepting)
        merged_some += len(members) < ba.num_states
    assert merged_some > 100  # the copies make merges to find
