"""A recurrence that may give up: ``G F a | e`` with ``e`` a pure eventuality is one VWAA
state (:mod:`planner.ltl.vwaa`), checked against the direct lasso semantics."""

from __future__ import annotations

import random

import pytest

from planner.ltl.families import gh_r
from planner.ltl.formula import (
    And,
    Eventually,
    Formula,
    Globally,
    Next,
    Or,
    Prop,
    Until,
    parse,
    to_nnf,
)
from planner.ltl.gba import Degeneralizer
from planner.ltl.reduce import reduce_buchi
from planner.ltl.rewrite import simplify
from planner.ltl.translate import raw_size, translate
from planner.ltl.vwaa import build_vwaa
from tests.planner.ltl_random import check_semantics, random_formula


def _small(rng: random.Random) -> Formula:
    return random_formula(rng, depth=1, allow_next=rng.random() < 0.3)


def _eventuality(rng: random.Random, depth: int = 2) -> Formula:
    """A random pure eventuality: ``F x``, ``G F x``, ``F G x`` and what keeps them so."""
    kind = rng.choice(["F", "GF", "FG"] + (["X", "&", "|", "U"] if depth else []))
    if kind == "F":
        return Eventually(_small(rng))
    if kind == "GF":
        return Globally(Eventually(_small(rng)))
    if kind == "FG":
        return Eventually(Globally(_small(rng)))
    if kind == "X":
        return Next(_eventuality(rng, depth - 1))
    if kind == "U":
        return Until(_small(rng), _eventuality(rng, depth - 1))
    combine = And if kind == "&" else Or
    return combine(_eventuality(rng, depth - 1), _eventuality(rng, depth - 1))


def _giving_up(rng: random.Random) -> Formula:
    """``G F a | e``, either way round, alone or inside ``G``, ``X``, ``U`` or ``&``."""
    recurrence = Globally(Eventually(_small(rng)))
    e = _eventuality(rng)
    f: Formula = Or(recurrence, e) if rng.random() < 0.5 else Or(e, recurrence)
    context = rng.choice(["", "G", "X", "U", "&"])
    if context == "G":
        return Globally(f)
    if context == "X":
        return Next(f)
    if context == "U":
        return Until(_small(rng), f)
    if context == "&":
        return And(f, random_formula(rng, depth=2))
    return f


def test_random_recurrences_that_give_up_agree_with_semantics() -> None:
    rng = random.Random(23)
    made_states = 0
    for _ in range(150):
        f = _giving_up(rng)
        made_states += build_vwaa(simplify(to_nnf(f))).gives_up
        check_semantics(f, rng, words=40)
    assert made_states >= 60  # the rewriting leaves most of them for the new state


@pytest.mark.parametrize(
    "text",
    [
        "G F a | b",  # b holds now or never: not an eventuality
        "G F a | G b",
        "G F a | (b R F c)",
        "G F a | X b",
        "G F a | (b U c)",
        "G F a | (F b & c)",
    ],
)
def test_a_disjunct_that_is_no_eventuality_keeps_the_split(text: str) -> None:
    f = parse(text)
    assert not build_vwaa(simplify(to_nnf(f))).gives_up
    check_semantics(f, random.Random(5), words=200)


def test_a_late_eventuality_does_not_pass_for_an_early_one() -> None:
    """``G F a | F b`` may give up for ``b`` at any time, ``G F a | b`` only now."""
    f = parse("G F a | F b")
    assert build_vwaa(simplify(to_nnf(f))).gives_up
    nba = translate(f)
    b = frozenset({"b"})
    none: frozenset[str] = frozenset()
    assert nba.accepts_lasso([none, none, b], [none])
    assert not nba.accepts_lasso([none], [none])
    assert not translate(parse("G F a | b")).accepts_lasso([none, b], [none])


def test_gh_r_has_one_state_per_conjunct_and_two_per_conjunct_in_the_automaton() -> None:
    """``(G F p1 | F G p2) & ...``: one initial set of n recurrences, 2^n sets in all."""
    for n in (3, 5):
        vwaa = build_vwaa(simplify(to_nnf(parse(gh_r(n)))))
        assert len(vwaa.initial) == 1 and len(vwaa.initial[0]) == n
        sets = {e for e, _ in _reachable(Degeneralizer(vwaa))}
        assert len(sets) == 2**n


def _reachable(d: Degeneralizer) -> set[tuple[frozenset[int], int]]:
    seen = {(d.vwaa.initial[0], 0)}
    todo = list(seen)
    while todo:
        for target in d.successors(*todo.pop()):
            if target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def test_the_split_automaton_is_kept_where_its_reduction_is_smaller() -> None:
    """``gh_r(6)`` reduces to 107 states split and 195 as recurrences that give up, and
    ``translate`` keeps the split; ``gh_r(7)`` split (896 states) has over half the states
    the simulation affords, so ``translate`` keeps the joined automaton (427 states)."""
    nnf = simplify(to_nnf(parse(gh_r(6))))
    split = raw_size(reduce_buchi(Degeneralizer(build_vwaa(nnf, give_up=False)).build()))
    joined = raw_size(reduce_buchi(Degeneralizer(build_vwaa(nnf)).build()))
    assert split < joined
    assert translate(gh_r(6)).num_states == split[0]
    nnf = simplify(to_nnf(parse(gh_r(7))))
    joined = raw_size(reduce_buchi(Degeneralizer(build_vwaa(nnf)).build()))
    assert translate(gh_r(7)).num_states == joined[0] < 2444  # ltl2ba 1.1


def test_a_proposition_is_not_an_eventuality() -> None:
    assert not build_vwaa(Or(Globally(Eventually(Prop("a"))), Prop("b"))).gives_up


def test_a_recurrence_does_not_give_way_where_staying_is_no_better() -> None:
    """``gh_r(9)``: the moves that leave for ``G p`` are built only where staying would miss
    the recurrence's acceptance set first, and only on letters where it could not stay
    marked (23109 cubes before any reduction; 76861 on every letter, 259503 with every
    move), and ``gh_r(7)`` and ``gh_r(8)`` still agree with the semantics."""
    vwaa = build_vwaa(simplify(to_nnf(parse(gh_r(9)))))
    assert raw_size(Degeneralizer(vwaa).build())[1] < 30_000
    for n in (7, 8):
        check_semantics(parse(gh_r(n)), random.Random(n), words=300)
