"""Language-preserving reductions of Büchi automata with cube-labelled transitions.

Gastin and Oddoux merge equivalent states and drop dominated transitions. We do the same
with direct simulation, which subsumes both: a state ``p`` is simulated by ``p'`` when
``p'`` is accepting whenever ``p`` is and can answer every transition of ``p`` with a
transition to a state that again simulates the target. Then

- mutually simulating states are merged (quotient), and
- a cube to ``p`` is dropped when transitions of the same source to states strictly
  simulating ``p`` cover it ("little brothers", Bustan and Grumberg 2003),

and finally states that are unreachable or cannot reach an accepting cycle go.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from planner.ltl.gba import RawBuchi, add_cube
from planner.ltl.guard import Cube, covers
from planner.ltl.letter_simulation import letter_simulation, letter_words
from planner.ltl.trim import trim

LETTER_ATOMS = 8
"""Up to this many atoms the simulation reasons letter by letter (2^8 letters)."""

LETTER_SIMULATION_BUDGET = 4_000_000
"""Largest ``states^2 x letter words`` for which the letter simulation is computed."""

SIMULATION_BUDGET = 150_000
"""Above :data:`LETTER_ATOMS` atoms: the largest ``states x cubes`` for which the
quadratic simulation is computed (~0.5 s)."""


def reduce_buchi(ba: RawBuchi) -> RawBuchi:
    """Apply trimming, simulation quotient and little-brother pruning until stable.

    Automata too large for the simulation budget (rare: deeply nested formulas with many
    until operators) get only the cheap merge of identical states.
    """
    ba = trim(ba)
    merged = merge_identical(ba)
    if merged is not ba:
        ba = trim(merged)
    while True:
        size = (ba.num_states, _num_cubes(ba))
        if not _within_budget(ba, cubes=size[1]):
            return ba
        sim = simulation(ba)
        merged = quotient(ba, sim)
        if merged is not ba:
            ba = trim(merged)
            sim = simulation(ba)
        # Pruning keeps every state's language, so its simulation still orders them.
        ba = trim(restart_initial(prune_little_brothers(ba, sim), sim))
        if (ba.num_states, _num_cubes(ba)) == size:
            return ba


def _num_cubes(ba: RawBuchi) -> int:
    return sum(sum(map(len, out.values())) for out in ba.edges.values())


def _atoms(ba: RawBuchi) -> list[str]:
    # Cubes are shared between transitions: each distinct one is read once.
    cubes = {id(c): c for out in ba.edges.values() for cs in out.values() for c in cs}
    return sorted({a for c in cubes.values() for a in c.atoms})


def simulation_affordable(ba: RawBuchi) -> bool:
    """Whether :func:`reduce_buchi` computes the simulation of ``ba`` (else it only merges
    identical states)."""
    return _within_budget(ba, cubes=_num_cubes(ba))


def affordable_states(atoms: int) -> int:
    """An upper bound on the states of an automaton over ``atoms`` atoms whose simulation
    :func:`reduce_buchi` computes (with at least one cube per state)."""
    if atoms <= LETTER_ATOMS:
        return math.isqrt(LETTER_SIMULATION_BUDGET // letter_words(atoms))
    return math.isqrt(SIMULATION_BUDGET)


def _within_budget(ba: RawBuchi, cubes: int) -> bool:
    states = ba.num_states
    if states * cubes > SIMULATION_BUDGET and states**2 > LETTER_SIMULATION_BUDGET:
        return False  # over both budgets whatever its atoms: no need to collect them
    atoms = len(_atoms(ba))
    if atoms <= LETTER_ATOMS:
        return states**2 * letter_words(atoms) <= LETTER_SIMULATION_BUDGET
    return states * cubes <= SIMULATION_BUDGET


def simulation(ba: RawBuchi) -> list[set[int]]:
    """``sim[p]``: the states that directly simulate ``p`` (``p`` itself included).

    Up to :data:`LETTER_ATOMS` atoms by :func:`letter_simulation` on bit arrays, above by
    :func:`cube_simulation`.
    """
    names = _atoms(ba)
    if len(names) <= LETTER_ATOMS:
        return [set(np.flatnonzero(row).tolist()) for row in letter_simulation(ba, names)]
    return cube_simulation(ba)


def cube_simulation(ba: RawBuchi) -> list[set[int]]:
    """:func:`simulation` on the cubes, for any number of atoms.

    Greatest fixpoint by a worklist: a state is re-examined only when the simulators of
    one of its successors shrink. Relations and cubes are bit masks; for each transition
    of ``p`` and candidate ``q`` the targets that ``q`` reaches under a weaker cube are
    cached, so most checks are one mask intersection and only the rest need a cover test.
    """
    names = _atoms(ba)
    n = ba.num_states
    bit = {a: 1 << i for i, a in enumerate(names)}
    flat: list[list[tuple[int, Cube, int, int]]] = []
    pred: list[set[int]] = [set() for _ in range(n)]
    for p in range(n):
        row = []
        for t, cubes in ba.edges.get(p, {}).items():
            pred[t].add(p)
            for c in cubes:
                row.append((t, c, sum(bit[a] for a in c.pos), sum(bit[a] for a in c.neg)))
        flat.append(row)
    accepting_mask = sum(1 << q for q in ba.accepting)
    everyone = (1 << n) - 1
    sim = [accepting_mask if p in ba.accepting else everyone for p in range(n)]
    implied: dict[tuple[int, int, int], int] = {}

    def answers(p: int, q: int) -> bool:
        for i, (target, cube, pos, neg) in enumerate(flat[p]):
            key = (p, i, q)
            weaker = implied.get(key)
            if weaker is None:
                weaker = 0
                for t, _, pos2, neg2 in flat[q]:
                    if not (pos2 & ~pos or neg2 & ~neg):
                        weaker |= 1 << t
                implied[key] = weaker
            good = sim[target]
            if weaker & good:
                continue
            candidates = [
                c
                for t, c, pos2, neg2 in flat[q]
                if good >> t & 1 and not (pos2 & neg or neg2 & pos)
            ]
            if not covers(candidates, cube):
                return False
        return True

    queue = list(range(n))
    queued = set(queue)
    while queue:
        p = queue.pop()
        queued.discard(p)
        removed = 0
        for q in range(n):
            if q != p and sim[p] >> q & 1 and not answers(p, q):
                removed |= 1 << q
        if removed:
            sim[p] &= ~removed
            for r in pred[p]:
                if r not in queued:
                    queued.add(r)
                    queue.append(r)
    return [{q for q in range(n) if sim[p] >> q & 1} for p in range(n)]


def quotient(ba: RawBuchi, sim: list[set[int]]) -> RawBuchi:
    """Merge classes of mutually simulating states, keeping the lowest id of each class."""
    n = ba.num_states
    rep = list(range(n))
    for p in range(n):
        for q in sorted(sim[p]):
            if q < rep[p] and p in sim[q]:
                rep[p] = q
    if all(rep[p] == p for p in range(n)):
        return ba
    edges: dict[int, dict[int, list[Cube]]] = {}
    for p, out in ba.edges.items():
        merged = edges.setdefault(rep[p], {})
        for target, cubes in out.items():
            bucket = merged.setdefault(rep[target], [])
            for cube in cubes:
                add_cube(bucket, cube)
    accepting = {rep[p] for p in ba.accepting}
    return RawBuchi(rep[ba.initial], accepting, edges, list(ba.names))


def prune_little_brothers(ba: RawBuchi, sim: list[set[int]]) -> RawBuchi:
    """Drop cubes covered by transitions of the same state to strictly better targets."""
    edges: dict[int, dict[int, list[Cube]]] = {}
    for p, out in ba.edges.items():
        kept: dict[int, list[Cube]] = {}
        for target, cubes in out.items():
            better = [
                c
                for t in sim[target] & out.keys()
                if t != target and target not in sim[t]
                for c in out[t]
            ]
            remaining = [c for c in cubes if not covers(better, c)]
            if remaining:
                kept[target] = remaining
        edges[p] = kept
    return RawBuchi(ba.initial, set(ba.accepting), edges, list(ba.names))


def restart_initial(ba: RawBuchi, sim: list[set[int]]) -> RawBuchi:
    """Start in another state when the initial state is one of its copies.

    An initial state without incoming transitions is visited once, so whether it accepts
    does not matter (ltl2ba's rule for the initial state). If another state ``q`` answers
    each transition of the initial state with one to a simulating target and the other
    way round, both accept the same words and ``q`` can be the start. Degeneralization
    makes such copies: ``G (a -> F b)`` starts at level 0 beside its accepting level.
    """
    p = ba.initial
    if any(p in out for out in ba.edges.values()):
        return ba
    for q in range(ba.num_states):
        if q != p and _answers(ba, sim, p, q) and _answers(ba, sim, q, p):
            return RawBuchi(q, set(ba.accepting), ba.edges, list(ba.names))
    return ba


def _answers(ba: RawBuchi, sim: list[set[int]], p: int, q: int) -> bool:
    """Whether ``q`` answers every transition of ``p`` with one to a simulating target."""
    q_out = ba.edges.get(q, {})
    for target, cubes in ba.edges.get(p, {}).items():
        better = [c for t, cs in q_out.items() if t in sim[target] for c in cs]
        if not all(covers(better, c) for c in cubes):
            return False
    return True


def merge_identical(ba: RawBuchi) -> RawBuchi:
    """Merge states with the same acceptance and the same guards to the same classes.

    This is the coarsest such partition (computed by refinement); it is cheap and shrinks
    the automaton before the quadratic simulation computation. The first split is by the
    fewest-literal cubes to each acceptance class, which identical states share (such a cube
    is implied by no other, so joining guards keeps it), and is cheaper than joining every
    guard; a state alone in its class is never split again, so its guards are not joined.
    """
    n = ba.num_states
    accepting = [1 if p in ba.accepting else 0 for p in range(n)]
    literals: dict[int, int] = {}
    first: dict[object, int] = {}
    block = [
        first.setdefault(
            (accepting[p], _fewest_literal_cubes(ba.edges.get(p, {}), accepting, literals)),
            len(first),
        )
        for p in range(n)
    ]
    count = len(first)
    while count < n:
        sizes = Counter(block)
        signatures: dict[object, int] = {}
        new_block = []
        for p in range(n):
            if sizes[block[p]] == 1:
                sig: object = block[p]
            else:
                out = _guards_by_block(ba.edges.get(p, {}), block)
                sig = (block[p], frozenset((b, frozenset(cs)) for b, cs in out.items()))
            new_block.append(signatures.setdefault(sig, len(signatures)))
        block = new_block
        if len(signatures) == count:  # no block split: the partition is stable
            break
        count = len(signatures)
    members: dict[int, set[int]] = {}
    for p in range(n):
        members.setdefault(block[p], set()).add(p)
    return quotient(ba, [members[block[p]] for p in range(n)])


def _fewest_literal_cubes(
    out: dict[int, list[Cube]], block: list[int], literals: dict[int, int]
) -> frozenset[tuple[int, frozenset[Cube]]]:
    """For each block of ``out``'s targets, its cubes with the fewest literals (``literals``
    caches each cube's count by id)."""
    fewest: dict[int, tuple[int, list[Cube]]] = {}
    for target, cubes in out.items():
        b = block[target]
        found = fewest.get(b)
        for cube in cubes:
            count = literals.get(id(cube))
            if count is None:
                count = literals[id(cube)] = len(cube.pos) + len(cube.neg)
            if found is None or count < found[0]:
                found = fewest[b] = (count, [cube])
            elif count == found[0]:
                found[1].append(cube)
    return frozenset((b, frozenset(cubes)) for b, (_, cubes) in fewest.items())


def _guards_by_block(out: dict[int, list[Cube]], block: list[int]) -> dict[int, list[Cube]]:
    """The guards of ``out`` joined by the targets' blocks (a lone target's list is shared)."""
    joined: dict[int, list[Cube]] = {}
    own: set[int] = set()
    for target, cubes in out.items():
        b = block[target]
        bucket = joined.get(b)
        if bucket is None:
            joined[b] = cubes
            continue
        if b not in own:
            bucket = joined[b] = list(bucket)
            own.add(b)
        for cube in cubes:
            add_cube(bucket, cube)
    return joined
