"""Seeded random LTL formulas and lasso words for the translator tests (test helper)."""

from __future__ import annotations

import random
from collections.abc import Callable

from planner.ltl.formula import (
    And,
    Const,
    Eventually,
    Formula,
    Globally,
    Iff,
    Implies,
    Next,
    Not,
    Or,
    Prop,
    Release,
    Until,
    WeakUntil,
    atoms,
    to_text,
)
from planner.ltl.semantics import holds_on_lasso
from planner.ltl.translate import translate

PROPS = ("a", "b", "c")
Lasso = tuple[list[frozenset[str]], list[frozenset[str]]]

_UNARY: dict[str, Callable[[Formula], Formula]] = {
    "!": Not,
    "X": Next,
    "G": Globally,
    "F": Eventually,
}
_BINARY: dict[str, Callable[[Formula, Formula], Formula]] = {
    "&": And,
    "|": Or,
    "->": Implies,
    "<->": Iff,
    "U": Until,
    "R": Release,
    "W": WeakUntil,
}
# Weights keep spin's run time reasonable: it is slow on nested R/W and <->.
_WEIGHTS = {"!": 2, "G": 2, "F": 2, "X": 2, "&": 2, "|": 2, "->": 1, "<->": 1}
_WEIGHTS |= {"U": 2, "R": 1, "W": 1}


def random_formula(
    rng: random.Random, depth: int = 4, allow_next: bool = True, leaf: float = 0.3
) -> Formula:
    """A formula of nesting depth at most ``depth`` over :data:`PROPS` using every operator."""
    if depth == 0 or rng.random() < leaf:
        if rng.random() < 0.04:
            return Const(rng.random() < 0.5)
        return Prop(rng.choice(PROPS))
    ops = [op for op in _WEIGHTS if allow_next or op != "X"]
    op = rng.choices(ops, [_WEIGHTS[o] for o in ops])[0]
    if op in _UNARY:
        return _UNARY[op](random_formula(rng, depth - 1, allow_next, leaf))
    left = random_formula(rng, depth - 1, allow_next, leaf)
    return _BINARY[op](left, random_formula(rng, depth - 1, allow_next, leaf))


def random_letter(rng: random.Random, props: tuple[str, ...] = PROPS) -> frozenset[str]:
    """A uniformly random subset of ``props``."""
    return frozenset(p for p in props if rng.random() < 0.5)


def random_lasso(rng: random.Random, props: tuple[str, ...] = PROPS, longest: int = 4) -> Lasso:
    """A word ``u v^ω`` with ``1 <= |u|, |v| <= longest``."""
    prefix = [random_letter(rng, props) for _ in range(rng.randint(1, longest))]
    cycle = [random_letter(rng, props) for _ in range(rng.randint(1, longest))]
    return prefix, cycle


def check_semantics(f: Formula, rng: random.Random, words: int = 40) -> None:
    """``translate(f)`` accepts exactly the random lassos on which ``f`` holds (over ``f``'s
    atoms), by the direct semantics :func:`holds_on_lasso`, which builds no automaton."""
    nba = translate(f)
    props = tuple(sorted(atoms(f))) or ("a",)
    for _ in range(words):
        prefix, cycle = random_lasso(rng, props, longest=5)
        expected = holds_on_lasso(f, prefix, cycle)
        assert nba.accepts_lasso(prefix, cycle) == expected, (to_text(f), prefix, cycle)
