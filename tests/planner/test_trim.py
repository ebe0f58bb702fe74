"""``trim`` against the definition: reachable states that can reach an accepting cycle."""

from __future__ import annotations

import random

from planner.ltl.gba import RawBuchi
from planner.ltl.guard import Cube
from planner.ltl.trim import trim


def _reach(start: int, edges: dict[int, dict[int, list[Cube]]]) -> set[int]:
    seen = {start}
    todo = [start]
    while todo:
        for t, cubes in edges.get(todo.pop(), {}).items():
            if cubes and t not in seen:
                seen.add(t)
                todo.append(t)
    return seen


def _random_automaton(rng: random.Random) -> RawBuchi:
    n = rng.randint(1, 12)
    edges = {
        p: {
            t: [Cube.literal(f"a{t}")] if rng.random() < 0.9 else []
            for t in rng.sample(range(n), rng.randint(0, min(n, 3)))
        }
        for p in range(n)
        if rng.random() < 0.9
    }
    accepting = set(rng.sample(range(n), rng.randint(0, n)))
    return RawBuchi(rng.randrange(n), accepting, edges, [f"q{p}" for p in range(n)])


def test_trim_keeps_exactly_the_useful_states_renumbered_breadth_first() -> None:
    rng = random.Random(11)
    for _ in range(2000):
        ba = _random_automaton(rng)
        reach = {p: _reach(p, ba.edges) for p in range(ba.num_states)}
        on_accepting_cycle = {
            q
            for q in ba.accepting
            if any(q in reach[t] for t, cubes in ba.edges.get(q, {}).items() if cubes)
        }
        useful = {p for p in reach[ba.initial] if reach[p] & on_accepting_cycle}
        trimmed = trim(ba)
        kept = [ba.names.index(name) for name in trimmed.names]
        assert kept[0] == ba.initial
        assert set(kept) == useful | {ba.initial}
        # Breadth-first: each state after the first is first reached from an earlier one.
        for i, p in enumerate(kept[1:], 1):
            assert any(p in ba.edges.get(q, {}) for q in kept[:i])
        assert trimmed.accepting == {i for i, p in enumerate(kept) if p in ba.accepting}
        for i, p in enumerate(kept):
            expected = {
                kept.index(t): cubes
                for t, cubes in ba.edges.get(p, {}).items()
                if cubes and t in kept
            }
            assert trimmed.edges[i] == expected
