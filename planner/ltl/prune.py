"""The truncated NBA of Kantaros et al.: what is left of a Büchi automaton in a given world.

A world cannot produce every letter: two disjoint regions are never true together and the
robot never stands in an obstacle. Transitions whose guard needs such a letter are dead
weight for the planner (it would sample toward them forever), and so are states that can
no longer reach an accepting cycle once they are gone.
"""

from __future__ import annotations

from collections.abc import Callable

from planner.ltl.automaton import Buchi, Edge
from planner.ltl.gba import RawBuchi
from planner.ltl.guard import Cube, Guard
from planner.ltl.trim import trim


def prune(nba: Buchi, realisable: Callable[[Cube], bool]) -> Buchi:
    """Drop the cubes the world cannot realise, then the states that became useless.

    ``realisable(cube)`` says whether some free point of the world satisfies ``cube``
    (typically ``lambda c: world.realisable(c.pos, c.neg)``); it is called once per
    distinct cube. The initial state is always kept, so the result may accept nothing:
    check :func:`has_accepting_run`. States keep their names and are renumbered breadth
    first from the initial state (id 0).
    """
    verdict: dict[Cube, bool] = {}

    def ok(cube: Cube) -> bool:
        if cube not in verdict:
            verdict[cube] = bool(realisable(cube))
        return verdict[cube]

    edges: dict[int, dict[int, list[Cube]]] = {q: {} for q in range(nba.num_states)}
    for e in nba.edges:
        kept = [c for c in e.guard.sorted_cubes() if ok(c)]
        if kept:
            edges[e.source][e.target] = kept
    raw = RawBuchi(nba.initial, set(nba.accepting), edges, list(nba.state_names))
    small = trim(raw)
    return Buchi(
        atoms=nba.atoms,
        state_names=tuple(map(str, small.names)),
        initial=small.initial,
        accepting=frozenset(small.accepting),
        edges=tuple(
            Edge(source, Guard.of(cubes), target)
            for source in sorted(small.edges)
            for target, cubes in sorted(small.edges[source].items())
        ),
    )


def has_accepting_run(nba: Buchi) -> bool:
    """Whether some run from the initial state visits an accepting state infinitely often.

    Equivalently, whether the automaton accepts at least one infinite word.
    """
    return nba.initial in nba.distances_to_acceptance()
