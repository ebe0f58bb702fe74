"""Very weak alternating automata (VWAA) from LTL, after Gastin and Oddoux (CAV 2001).

A VWAA state is a subformula; its transitions are pairs ``(cube, conjunction of
successor states)``. The translation is the paper's ``Δ``:

- ``Δ(a U b) = Δ(b) ∪ (Δ(a) ⊗ {(true, {a U b})})``
- ``Δ(a R b) = Δ(b) ⊗ (Δ(a) ∪ {(true, {a R b})})``
- ``Δ(X a) = {(true, e) | e ∈ ā}`` where ``ā`` is the DNF of ``a`` over states,

with ``⊗`` the pairwise conjunction and only minimal transitions kept (a transition with
a stronger cube and more successors than another is dropped).

Acceptance is on transitions, as in LTL3BA (Babiak et al., TACAS 2012): a *final* state
must not be stayed in forever along a branch unless infinitely many of the transitions it
takes there are marked. ``a U b`` marks the transitions that leave it. ``G F a`` is its
own final state with ``δ(G F a) = marked(Δ(a) ⊗ {G F a}) ∪ {(true, {G F a})}``; without
this, a conjunction of k ``G F`` formulas yields 2^k intermediate automaton states.

A disjunction ``G F a | e`` with ``e`` a pure eventuality (``e`` holds on a word once it
holds on a suffix: ``F b``, ``F G b``, ``G F b``, ...) is one final state too, a recurrence
that may give up: it stays as ``G F a`` does, or leaves for ``e``'s obligations, at once or
later (``e = F b``: for ``b``'s). Splitting it instead makes two branches that both wait, and
``(G F p1 | F G p2) & ... & (G F pn | F G pn+1)`` has 3^n automaton states instead of 2^n.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from itertools import permutations

from planner.ltl.formula import (
    And,
    Const,
    Eventually,
    Formula,
    Globally,
    Next,
    Not,
    Or,
    Prop,
    Release,
    Until,
    WeakUntil,
    to_text,
)
from planner.ltl.guard import Cube

Term = tuple[Cube, frozenset[int]]


@dataclass(frozen=True)
class Move:
    """One VWAA transition of a state: read a letter in ``cube``, go to all of ``targets``.

    ``marked`` matters only for final states: it says the transition discharges the
    state's obligation.
    """

    cube: Cube
    targets: frozenset[int]
    marked: bool


@dataclass
class Vwaa:
    """The VWAA of one NNF formula, built lazily from its initial state sets."""

    formulas: list[Formula] = field(default_factory=list)
    index: dict[Formula, int] = field(default_factory=dict)
    moves: dict[int, tuple[Move, ...]] = field(default_factory=dict)
    initial: list[frozenset[int]] = field(default_factory=list)
    finals: list[int] = field(default_factory=list)
    final_free: frozenset[int] = frozenset()
    gives_up: bool = False
    """Whether a state is a recurrence that may give up (``G F a | e``)."""

    def name(self, q: int) -> str:
        """A readable name of state ``q`` (its formula)."""
        return to_text(self.formulas[q])


def build_vwaa(nnf: Formula, give_up: bool = True) -> Vwaa:
    """The VWAA of ``nnf`` (negation normal form, ``W`` allowed), with every reachable state.

    With ``give_up`` false, ``G F a | e`` is split into its disjuncts as any disjunction.

    ``finals`` lists the final states in order of creation, outermost subformulas first,
    the ``G F`` states last; that order is the order of the acceptance sets after
    degeneralization. ``G F`` last keeps the level at 0 while an ``F`` or ``U`` obligation
    is pending (``G F a & F G b``: 3 states, not 4). ``final_free`` holds the states from
    which no final state can be reached.
    """
    builder = _Builder(give_up)
    vwaa = builder.vwaa
    vwaa.initial = builder.bar(_unweak(nnf))
    todo = sorted({q for e in vwaa.initial for q in e})
    done: set[int] = set()
    while todo:
        q = todo.pop(0)
        if q in done:
            continue
        done.add(q)
        vwaa.moves[q] = builder.state_moves(q)
        for move in vwaa.moves[q]:
            todo.extend(sorted(move.targets - done))
    vwaa.finals = sorted(q for q in done if _is_final(vwaa.formulas[q]))
    vwaa.finals.sort(key=lambda q: _is_recurrence(vwaa.formulas[q]))
    free = {q for q in done if q not in vwaa.finals}
    shrinking = True
    while shrinking:
        bad = {q for q in free if any(not m.targets <= free for m in vwaa.moves[q])}
        free -= bad
        shrinking = bool(bad)
    vwaa.final_free = frozenset(free)
    vwaa.gives_up = any(isinstance(vwaa.formulas[q], Or) for q in done)
    return vwaa


def _unweak(f: Formula) -> Formula:
    """Replace ``a W b`` by the equivalent ``b R (a | b)``."""
    if isinstance(f, WeakUntil):
        left, right = _unweak(f.left), _unweak(f.right)
        return Release(right, Or(left, right))
    if isinstance(f, Not | Next | Globally | Eventually):
        return type(f)(_unweak(f.arg))
    if isinstance(f, And | Or | Until | Release):
        return type(f)(_unweak(f.left), _unweak(f.right))
    return f


ALL_ORDERS_UP_TO = 4
"""Up to this many ``F``/``U`` obligations every order of their acceptance sets is worth
trying (24 orders at most): Dwyer's pattern 50 has 25 states in the two orders of the rule
below and 11 in the best of its 24 (ltl2ba 1.1: 24)."""


def reordered_finals(vwaa: Vwaa) -> Vwaa | None:
    """The same VWAA with the other order of acceptance sets worth trying first, if any.

    The innermost ``F``/``U`` obligations first instead of the outermost (``G F`` stay
    last). Neither order is always better: across Dwyer's patterns each wins on some
    (``G (a -> F (b & X F c))``: 5 states innermost first, 7 outermost first).
    """
    plain = [q for q in vwaa.finals if not _is_recurrence(vwaa.formulas[q])]
    if len(plain) < 2:
        return None
    recurring = [q for q in vwaa.finals if _is_recurrence(vwaa.formulas[q])]
    return replace(vwaa, finals=[*reversed(plain), *recurring])


def other_orders(vwaa: Vwaa) -> Iterator[Vwaa]:
    """The same VWAA with each other order of acceptance sets worth trying: the reversed
    one (``reordered_finals``), then, up to ``ALL_ORDERS_UP_TO`` obligations, every other
    order of the ``F``/``U`` obligations (``G F`` stay last), in a fixed order."""
    reversed_order = reordered_finals(vwaa)
    if reversed_order is None:
        return
    yield reversed_order
    plain = [q for q in vwaa.finals if not _is_recurrence(vwaa.formulas[q])]
    if len(plain) > ALL_ORDERS_UP_TO:
        return
    recurring = [q for q in vwaa.finals if _is_recurrence(vwaa.formulas[q])]
    tried = [vwaa.finals, reversed_order.finals]
    for order in permutations(plain):
        finals = [*order, *recurring]
        if finals not in tried:
            yield replace(vwaa, finals=finals)


def _is_gf(f: Formula) -> bool:
    return isinstance(f, Globally) and isinstance(f.arg, Eventually)


def _is_recurrence(f: Formula) -> bool:
    """``G F a``, or ``G F a | e`` with ``e`` a pure eventuality: a final state whose
    obligation recurs (its acceptance set comes after the ``F``/``U`` obligations')."""
    return _is_gf(f) or _giving_up(f) is not None


def _giving_up(f: Formula) -> tuple[Formula, list[Formula]] | None:
    """``(a, [e1, ..., ek])`` for ``f = G F a | e1 | ... | ek`` (in any order; the first
    ``G F`` disjunct is the recurrence) with every ``ei`` a pure eventuality, else None."""
    if not isinstance(f, Or):
        return None
    disjuncts = _disjuncts(f)
    for i, d in enumerate(disjuncts):
        if _is_gf(d):
            rest = disjuncts[:i] + disjuncts[i + 1 :]
            if all(_is_eventuality(e) for e in rest):
                return _recurring(d), rest
            return None
    return None


def _recurring(f: Formula) -> Formula:
    """``a`` of ``G F a``."""
    assert isinstance(f, Globally) and isinstance(f.arg, Eventually)
    return f.arg.arg


def _disjuncts(f: Formula) -> list[Formula]:
    if isinstance(f, Or):
        return _disjuncts(f.left) + _disjuncts(f.right)
    return [f]


def _is_eventuality(f: Formula) -> bool:
    """Whether ``f`` is a pure eventuality (syntactically): ``f`` holds on a word whenever it
    holds on one of its suffixes, so ``F f = f``."""
    if isinstance(f, Const | Eventually):
        return True
    if isinstance(f, Globally | Next):
        return _is_eventuality(f.arg)
    if isinstance(f, And | Or):
        return _is_eventuality(f.left) and _is_eventuality(f.right)
    if isinstance(f, Until):
        return _is_eventuality(f.right)
    return False


def _is_final(f: Formula) -> bool:
    return isinstance(f, Until | Eventually) or _is_recurrence(f)


def _minimal(terms: list[Term]) -> list[Term]:
    """Drop duplicated terms and terms dominated by a weaker cube with fewer successors."""
    unique = list(dict.fromkeys(terms))
    out = []
    for i, (cube, targets) in enumerate(unique):
        dominated = False
        for j, (other_cube, other_targets) in enumerate(unique):
            if i != j and cube.implies(other_cube) and other_targets <= targets:
                dominated = True
                break
        if not dominated:
            out.append((cube, targets))
    return out


def _product(xs: list[Term], ys: list[Term]) -> list[Term]:
    out = []
    for cube_x, targets_x in xs:
        for cube_y, targets_y in ys:
            cube = cube_x.conjoin(cube_y)
            if cube is not None:
                out.append((cube, targets_x | targets_y))
    return _minimal(out)


class _Builder:
    def __init__(self, give_up: bool) -> None:
        self.vwaa = Vwaa()
        self.cache: dict[Formula, list[Term]] = {}
        self.give_up = give_up

    def gives_up(self, f: Formula) -> bool:
        """Whether ``f`` is made one state that may give up its recurrence."""
        return self.give_up and _giving_up(f) is not None

    def state(self, f: Formula) -> int:
        if f not in self.vwaa.index:
            self.vwaa.index[f] = len(self.vwaa.formulas)
            self.vwaa.formulas.append(f)
        return self.vwaa.index[f]

    def bar(self, f: Formula) -> list[frozenset[int]]:
        """The DNF of ``f`` over states: a list of alternative state sets."""
        if isinstance(f, Const):
            return [frozenset()] if f.value else []
        if isinstance(f, Or) and not self.gives_up(f):
            sets = self.bar(f.left) + self.bar(f.right)
        elif isinstance(f, And):
            sets = [a | b for a in self.bar(f.left) for b in self.bar(f.right)]
        else:
            return [frozenset((self.state(f),))]
        unique = list(dict.fromkeys(sets))
        return [s for s in unique if not any(o < s for o in unique)]

    def delta(self, f: Formula) -> list[Term]:
        """``Δ(f)``: the transitions of ``f`` as an obligation, not as a state."""
        if f not in self.cache:
            self.cache[f] = self._delta(f)
        return self.cache[f]

    def _delta(self, f: Formula) -> list[Term]:
        true = Cube.TRUE
        if isinstance(f, Const):
            return [(true, frozenset())] if f.value else []
        if isinstance(f, Prop):
            return [(Cube.literal(f.name), frozenset())]
        if isinstance(f, Not):
            assert isinstance(f.arg, Prop), "the formula must be in negation normal form"
            return [(Cube.literal(f.arg.name, False), frozenset())]
        if isinstance(f, And):
            return _product(self.delta(f.left), self.delta(f.right))
        if isinstance(f, Or):
            if self.gives_up(f):
                return _minimal([(true, frozenset((self.state(f),))), *self.leaving(f)])
            return _minimal(self.delta(f.left) + self.delta(f.right))
        if isinstance(f, Next):
            return [(true, e) for e in self.bar(f.arg)]
        loop = [(true, frozenset((self.state(f),)))]
        if _is_gf(f):
            return loop
        if isinstance(f, Until):
            return _minimal(self.delta(f.right) + _product(self.delta(f.left), loop))
        if isinstance(f, Eventually):
            return _minimal(self.delta(f.arg) + loop)
        if isinstance(f, Release):
            return _product(self.delta(f.right), _minimal(self.delta(f.left) + loop))
        assert isinstance(f, Globally), f"unexpected formula {f!r}"
        return _product(self.delta(f.arg), loop)

    def leaving(self, f: Formula) -> list[Term]:
        """The moves by which ``G F a | e1 | ... | ek`` gives up its recurrence now: those
        of some ``ei``, of ``b`` for ``ei = F b`` (the waiting is the recurrence's own)."""
        split = _giving_up(f)
        assert split is not None
        terms: list[Term] = []
        for e in split[1]:
            terms += self.delta(e.arg if isinstance(e, Eventually) else e)
        return _minimal(terms)

    def state_moves(self, q: int) -> tuple[Move, ...]:
        """``δ(q)`` with the marks that discharge a final state's obligation."""
        f = self.vwaa.formulas[q]
        if _is_recurrence(f):
            split = _giving_up(f)
            recurring = split[0] if split is not None else _recurring(f)
            loop = frozenset((q,))
            marked = [Move(c, t | loop, True) for c, t in self.delta(recurring)]
            moves = [*marked, Move(Cube.TRUE, loop, False)]
            if split is not None:
                moves += [Move(c, t, q not in t) for c, t in self.leaving(f)]
            return tuple(m for m in moves if not _move_dominated(m, moves))
        return tuple(Move(c, t, q not in t) for c, t in self.delta(f))


def _move_dominated(move: Move, moves: list[Move]) -> bool:
    return any(
        other != move
        and move.cube.implies(other.cube)
        and other.targets <= move.targets
        and (other.marked or not move.marked)
        for other in moves
    )
