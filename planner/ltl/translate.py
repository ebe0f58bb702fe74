"""LTL to Büchi automaton translation (Gastin and Oddoux, CAV 2001, with symbolic guards).

Pipeline: parse -> negation normal form -> rewriting (:mod:`planner.ltl.rewrite`) ->
very weak alternating automaton (:mod:`planner.ltl.vwaa`) -> degeneralized Büchi automaton
through an implicit generalized Büchi automaton (:mod:`planner.ltl.gba`) -> simulation-based
reduction (:mod:`planner.ltl.reduce`), for several orders of the acceptance sets when the
formula has several ``F``/``U`` obligations (the smallest automaton wins; the first on a
tie): the reversed order, and with up to four obligations every order (Dwyer's pattern 50:
25 states in the first two, 11 in the best). Other orders are tried only when the first
made copies of a GBA state at several levels: of the 61 formulas of
``planner.ltl.families`` and of robot tasks (2-8 goals) with two orders, the second won on
12, never on one without such copies (``<>g1 && ... && <>g10``, 1024 states, is one: half
its translation time was the second order). Nor are they tried when the first automaton is
too large for the simulation: the orders differ mostly in the copies the simulation merges,
and another order's automaton would go unreduced too (seven ``(F p_i | G p_i+1) & G F p_i``
over 8 atoms: 2764 states, and no fewer in the other order). A formula with recurrences that
may give up (``G F a | F G b``: :mod:`planner.ltl.vwaa`) is translated with them split too
when that automaton has at most half the states the simulation affords (its simulation then
takes at most a quarter of the budget): split, ``gh_r(4)`` to ``gh_r(6)`` reduce to 33, 60 and
107 states (joined: 39, 88, 195); joined, ``gh_r(7)`` has 447 states before reduction (split:
896). Guards stay DNF cubes throughout; only the simulation, up to 8 atoms, reasons on letter
sets.
"""

from __future__ import annotations

from planner.collector import collection_paused
from planner.errors import AutomatonTooLargeError
from planner.ltl.automaton import Buchi, Edge
from planner.ltl.formula import Formula, atoms, parse, to_nnf
from planner.ltl.gba import Degeneralizer, RawBuchi
from planner.ltl.guard import Cube, Guard
from planner.ltl.reduce import affordable_states, reduce_buchi, simulation_affordable
from planner.ltl.rewrite import simplify
from planner.ltl.vwaa import build_vwaa, other_orders


@collection_paused()
def translate(formula: Formula | str, max_states: int | None = None) -> Buchi:
    """The Büchi automaton accepting exactly the infinite words that satisfy ``formula``.

    ``formula`` may be a parsed formula or text in spin or letter syntax (a syntax error
    raises :class:`~planner.errors.FormulaError`). The automaton's atoms are all atoms of
    the formula, sorted, even those the rewriting made irrelevant. With ``max_states`` the
    translation stops with :class:`~planner.errors.AutomatonTooLargeError` as soon as the automaton
    before reduction (or the successors of one of its states) outgrows it: a formula such as
    ``<>a1 && ... && <>a12`` needs 2^12 states and ran over two minutes unfinished.
    """
    f = parse(formula) if isinstance(formula, str) else formula
    nnf = simplify(to_nnf(f))
    vwaa = build_vwaa(nnf)
    first = Degeneralizer(vwaa, max_states)
    best = reduce_buchi(first.build())
    affordable = simulation_affordable(best)
    if not first.one_level_per_set and affordable:
        for other in other_orders(vwaa):
            try:
                candidate = reduce_buchi(Degeneralizer(other, max_states).build())
            except AutomatonTooLargeError:
                continue  # this order outgrew the budget: keep the others
            if raw_size(candidate) < raw_size(best):
                best = candidate
    if vwaa.gives_up and affordable:
        budget = affordable_states(len(atoms(nnf))) // 2
        try:
            split = Degeneralizer(build_vwaa(nnf, give_up=False), min(budget, max_states or budget))
            candidate = reduce_buchi(split.build())
        except AutomatonTooLargeError:
            pass  # split, the automaton is the larger, and slow to reduce
        else:
            if raw_size(candidate) < raw_size(best):
                best = candidate
    return to_buchi(best, tuple(sorted(atoms(f))))


def raw_size(raw: RawBuchi) -> tuple[int, int]:
    """States, then transitions (one per cube): the smaller automaton is kept."""
    return raw.num_states, sum(len(cs) for out in raw.edges.values() for cs in out.values())


def to_buchi(raw: RawBuchi, atom_names: tuple[str, ...]) -> Buchi:
    """Freeze a constructed automaton, naming states in the style of spin never claims.

    The initial state is ``init`` (``accept_init`` when accepting); the others are
    ``S<i>`` or ``accept_S<i>``. ``raw`` must be trimmed (initial state 0).
    """
    names = []
    for q in range(raw.num_states):
        base = "init" if q == raw.initial else f"S{q}"
        names.append(f"accept_{base}" if q in raw.accepting else base)
    guards: dict[frozenset[Cube], Guard] = {}
    of_list: dict[int, Guard] = {}  # lists of cubes are shared between transitions

    def guard(cubes: list[Cube]) -> Guard:
        key = frozenset(cubes)
        found = guards.get(key)
        if found is None:
            found = guards[key] = Guard(key)
        return found

    edges = []
    new_edge = tuple.__new__  # Edge(...) without its Python-level __new__: 10^5 edges
    for source in sorted(raw.edges):
        out = raw.edges[source]
        for target in sorted(out):
            cubes = out[target]
            found = of_list.get(id(cubes))
            if found is None:
                if not cubes:
                    continue
                found = of_list[id(cubes)] = guard(cubes)
            edges.append(new_edge(Edge, (source, found, target)))
    return Buchi(
        atoms=atom_names,
        state_names=tuple(names),
        initial=raw.initial,
        accepting=frozenset(raw.accepting),
        edges=tuple(edges),
    )
