"""Translator: sizes and times on the paper's formulas, semantics on random formulas."""

from __future__ import annotations

import random
import time

import pytest

from planner.errors import FormulaError
from planner.ltl.formula import parse, to_text
from planner.ltl.semantics import holds_on_lasso
from planner.ltl.translate import translate
from tests.planner.ltl_random import random_formula, random_lasso

L = frozenset


def sequence(k: int, prefix: str = "[]!o && ") -> str:
    """``<>(g1 && <>(g2 && ... <>gk))``, the paper's sequential task."""
    text = f"<>g{k}"
    for i in range(k - 1, 0, -1):
        text = f"<>(g{i} && {text})"
    return prefix + text


def recurrence(k: int, prefix: str = "") -> str:
    """``[]<>g1 && ... && []<>gk``, the paper's visit-forever task."""
    return prefix + " && ".join(f"[]<>g{i}" for i in range(1, k + 1))


# (formula, ltl2ba states, ltl2ba transitions) from the reference table.
REFERENCE = [
    ("[]!o && <>(g1 && <>(g2 && <>(g3 && <>gi)))", 5, 15),
    ("[]!o && []<>(g1 && <>(g2 && <>g3))", 9, 43),
    ("[]!o && <>g1 && <>g2 && <>g3", 8, 27),
    ("[]!o && []<>g1 && []<>g2 && []<>g3", 4, 13),
    (sequence(12), 13, 91),  # the table says 90; spin 6.5.2 prints 91 for this formula
]


def timed(text: str) -> tuple[int, int, float]:
    start = time.perf_counter()
    nba = translate(text)
    return nba.num_states, nba.num_transitions, time.perf_counter() - start


@pytest.mark.parametrize(("text", "states", "transitions"), REFERENCE)
def test_reference_formulas_are_small_and_fast(text: str, states: int, transitions: int) -> None:
    ours_states, ours_transitions, seconds = timed(text)
    assert ours_states <= states
    assert ours_transitions <= transitions
    assert seconds < 1.0


@pytest.mark.parametrize("k", list(range(1, 13)))
@pytest.mark.parametrize("prefix", ["", "[]!o && "])
def test_recurrence_conjunctions_stay_polynomial(k: int, prefix: str) -> None:
    states, transitions, seconds = timed(recurrence(k, prefix))
    assert states == k + 1
    # Level i waits for g_{i+1} and can jump to any later level: a triangle of edges.
    assert transitions <= (k + 1) * (k + 2) // 2 + k + 1
    assert seconds < 1.0


def test_twelve_goal_missions() -> None:
    repeated = "[]!o && []" + sequence(12, "")  # the 12-goal sequence, forever
    for text in (sequence(12), recurrence(12, "[]!obstacle && "), sequence(12, ""), repeated):
        states, _, seconds = timed(text)
        assert states == 13
        assert seconds < 1.0


def test_recurrence_automaton_accepts_exactly_the_fair_words() -> None:
    nba = translate(recurrence(12, "[]!o && "))
    goals = [L({f"g{i}"}) for i in range(1, 13)]
    assert nba.accepts_lasso([L()], goals)
    assert nba.accepts_lasso([], [L({f"g{i}" for i in range(1, 13)})])
    assert not nba.accepts_lasso([L()], goals[:11])
    assert not nba.accepts_lasso([L()], [*goals[:6], L({"o"}), *goals[6:]])
    assert nba.accepts_lasso([L({"o"}) - L({"o"})], list(reversed(goals)))


def test_sequence_automaton_respects_order_and_obstacles() -> None:
    nba = translate(REFERENCE[0][0])
    g1, g2, g3, gi = (L({g}) for g in ("g1", "g2", "g3", "gi"))
    assert nba.accepts_lasso([g1, L(), g2, g3, gi], [L()])
    assert nba.accepts_lasso([L({"g1", "g2", "g3", "gi"})], [L()])
    assert not nba.accepts_lasso([g2, g1, g3, gi], [L()])
    assert not nba.accepts_lasso([g1, g2, g3, gi], [L({"o"})])


@pytest.mark.parametrize(
    ("text", "states", "accepts", "rejects"),
    [
        ("true", 1, ([], [L()]), None),
        ("false", 1, None, ([], [L()])),
        ("a && !a", 1, None, ([], [L({"a"})])),
        ("X a", 3, ([L()], [L({"a"}), L()]), ([L({"a"})], [L()])),
        ("a U b", 2, ([L({"a"})], [L({"b"})]), ([L({"a"})], [L()])),
        ("F G a", 2, ([L()], [L({"a"})]), ([L()], [L({"a"}), L()])),
    ],
)
def test_small_cases(
    text: str,
    states: int,
    accepts: tuple[list[frozenset[str]], list[frozenset[str]]] | None,
    rejects: tuple[list[frozenset[str]], list[frozenset[str]]] | None,
) -> None:
    nba = translate(text)
    assert nba.num_states == states
    if accepts is not None:
        assert nba.accepts_lasso(*accepts)
    if rejects is not None:
        assert not nba.accepts_lasso(*rejects)


def test_atoms_keep_every_proposition_of_the_formula() -> None:
    assert translate("a || !a || b").atoms == ("a", "b")
    assert translate(parse("[]!o && <>g1")).atoms == ("g1", "o")


def test_syntax_errors_propagate() -> None:
    with pytest.raises(FormulaError):
        translate("[]!o &&")


def test_agrees_with_direct_semantics_on_random_formulas() -> None:
    """Independent of spin, and including X, which the installed spin cannot parse."""
    rng = random.Random(2024)
    for _ in range(250):
        f = random_formula(rng)
        nba = translate(f)
        for _ in range(20):
            prefix, cycle = random_lasso(rng)
            expected = holds_on_lasso(f, prefix, cycle)
            assert nba.accepts_lasso(prefix, cycle) == expected, (to_text(f), prefix, cycle)


def test_a_state_budget_stops_an_exponential_translation_and_spares_the_rest() -> None:
    from planner.errors import AutomatonTooLargeError

    twelve_goals = " && ".join(f"<>g{i}" for i in range(12))  # 2^12 states
    began = time.process_time()
    with pytest.raises(AutomatonTooLargeError, match="grows past 100 states"):
        translate(twelve_goals, max_states=100)
    assert time.process_time() - began < 2.0
    small = sequence(4)
    assert translate(small, max_states=100) == translate(small)
