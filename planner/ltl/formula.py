"""LTL formulas: the abstract syntax, a parser for the two usual concrete syntaxes, and
the transformations the translator and the planner need (negation normal form, atoms,
spin syntax, mission checks).

Two syntaxes are accepted and may be mixed: spin/ltl2ba (``[] <> ! && || -> <-> U V X``,
also ``/\\ \\/``) and the letter syntax of Spot and most papers (``G F X U R W & | ~``).
Atomic propositions are lowercase identifiers ``[a-z_][a-z0-9_]*``, so an uppercase
operator letter is always an operator: ``GFa`` reads as ``G F a`` (and ``Goal`` as ``G oal``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from planner.errors import FormulaError


@dataclass(frozen=True)
class Prop:
    """An atomic proposition (a region label)."""

    name: str


@dataclass(frozen=True)
class Const:
    """``true`` or ``false``."""

    value: bool


@dataclass(frozen=True)
class Not:
    """Negation."""

    arg: Formula


@dataclass(frozen=True)
class And:
    """Conjunction."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Or:
    """Disjunction."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Implies:
    """Implication ``left -> right``."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Iff:
    """Equivalence ``left <-> right``."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Next:
    """``X arg``: arg holds at the next position of the word."""

    arg: Formula


@dataclass(frozen=True)
class Until:
    """``left U right``: right eventually holds and left holds at every position before."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Release:
    """``left R right`` (spin: ``V``): right holds up to and including the first position
    where left holds, or forever."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class WeakUntil:
    """``left W right``: left holds until right does, or forever."""

    left: Formula
    right: Formula


@dataclass(frozen=True)
class Globally:
    """``G arg`` / ``[] arg``: arg holds at every position."""

    arg: Formula


@dataclass(frozen=True)
class Eventually:
    """``F arg`` / ``<> arg``: arg holds at some position."""

    arg: Formula


Formula = (
    Prop
    | Const
    | Not
    | And
    | Or
    | Implies
    | Iff
    | Next
    | Until
    | Release
    | WeakUntil
    | Globally
    | Eventually
)

TRUE = Const(True)
FALSE = Const(False)

_UNARY = (Not, Next, Globally, Eventually)
_BINARY = (And, Or, Implies, Iff, Until, Release, WeakUntil)


def children(f: Formula) -> tuple[Formula, ...]:
    """The direct subformulas of ``f``."""
    if isinstance(f, _UNARY):
        return (f.arg,)
    if isinstance(f, _BINARY):
        return (f.left, f.right)
    return ()


def atoms(f: Formula) -> frozenset[str]:
    """The atomic propositions that occur in ``f``."""
    if isinstance(f, Prop):
        return frozenset((f.name,))
    out: frozenset[str] = frozenset()
    for c in children(f):
        out |= atoms(c)
    return out


def uses_next(f: Formula) -> bool:
    """Whether ``f`` contains the next operator ``X``."""
    return isinstance(f, Next) or any(uses_next(c) for c in children(f))


def to_nnf(f: Formula) -> Formula:
    """Negation normal form: negations only in front of propositions, no ``->`` or ``<->``.

    The result uses ``Const, Prop, Not(Prop), And, Or, Next, Until, Release, WeakUntil,
    Globally, Eventually`` and is equivalent to ``f`` on infinite words.
    """
    return _nnf(f, positive=True)


def _nnf(f: Formula, positive: bool) -> Formula:
    if isinstance(f, Const):
        return Const(f.value == positive)
    if isinstance(f, Prop):
        return f if positive else Not(f)
    if isinstance(f, Not):
        return _nnf(f.arg, not positive)
    if isinstance(f, And | Or):
        left, right = _nnf(f.left, positive), _nnf(f.right, positive)
        return And(left, right) if isinstance(f, And) == positive else Or(left, right)
    if isinstance(f, Implies):
        return _nnf(Or(Not(f.left), f.right), positive)
    if isinstance(f, Iff):
        both = And(f.left, f.right)
        neither = And(Not(f.left), Not(f.right))
        if positive:
            return Or(_nnf(both, True), _nnf(neither, True))
        return And(_nnf(both, False), _nnf(neither, False))
    if isinstance(f, Next):
        return Next(_nnf(f.arg, positive))
    if isinstance(f, Globally):
        arg = _nnf(f.arg, positive)
        return Globally(arg) if positive else Eventually(arg)
    if isinstance(f, Eventually):
        arg = _nnf(f.arg, positive)
        return Eventually(arg) if positive else Globally(arg)
    if isinstance(f, Until):
        left, right = _nnf(f.left, positive), _nnf(f.right, positive)
        return Until(left, right) if positive else Release(left, right)
    if isinstance(f, Release):
        left, right = _nnf(f.left, positive), _nnf(f.right, positive)
        return Release(left, right) if positive else Until(left, right)
    # WeakUntil: !(a W b) = !b U (!a & !b).
    if positive:
        return WeakUntil(_nnf(f.left, True), _nnf(f.right, True))
    not_right = _nnf(f.right, False)
    return Until(not_right, And(_nnf(f.left, False), not_right))


def to_spin(f: Formula) -> str:
    """The formula in spin/ltl2ba syntax, fully parenthesised.

    ``R`` is written ``V`` and ``a W b`` as the equivalent ``b V (a || b)``, because spin
    knows neither; ``X`` is kept (ltl2ba reads it, a spin built without NXT does not).
    """
    if isinstance(f, Const):
        return "true" if f.value else "false"
    if isinstance(f, Prop):
        return f.name
    if isinstance(f, Not):
        return f"(! {to_spin(f.arg)})"
    if isinstance(f, Next):
        return f"(X {to_spin(f.arg)})"
    if isinstance(f, Globally):
        return f"([] {to_spin(f.arg)})"
    if isinstance(f, Eventually):
        return f"(<> {to_spin(f.arg)})"
    if isinstance(f, WeakUntil):
        left, right = to_spin(f.left), to_spin(f.right)
        return f"({right} V ({left} || {right}))"
    assert isinstance(f, _BINARY)
    op = {And: "&&", Or: "||", Implies: "->", Iff: "<->", Until: "U", Release: "V"}[type(f)]
    return f"({to_spin(f.left)} {op} {to_spin(f.right)})"


def to_text(f: Formula) -> str:
    """A readable rendering in letter syntax with the fewest parentheses that stay safe."""
    if isinstance(f, Const):
        return "true" if f.value else "false"
    if isinstance(f, Prop):
        return f.name
    if isinstance(f, _UNARY):
        op = {Not: "!", Next: "X ", Globally: "G ", Eventually: "F "}[type(f)]
        inner = to_text(f.arg)
        return f"{op}{inner}" if isinstance(f.arg, (Prop, Const, *_UNARY)) else f"{op}({inner})"
    assert isinstance(f, _BINARY)
    op = {And: "&", Or: "|", Implies: "->", Iff: "<->", Until: "U", Release: "R"}.get(type(f), "W")
    parts = []
    for side in (f.left, f.right):
        text = to_text(side)
        parts.append(text if isinstance(side, (Prop, Const, *_UNARY)) else f"({text})")
    return f"{parts[0]} {op} {parts[1]}"


@functools.lru_cache(maxsize=256)
def parse(text: str) -> Formula:
    """Parse an LTL formula in spin/ltl2ba or letter syntax.

    Raises :class:`FormulaError` with the 1-based column of the problem and what the parser
    expected there. A formula is parsed once per process: validating a mission, planning it
    and checking its labels ask for the same text, and the syntax tree is immutable.
    """
    from planner.ltl.parser import Parser

    return Parser(text).parse()


def check_mission_formula(f: Formula, text: str = "") -> None:
    """Reject formulas a navigation mission cannot mean.

    The next operator ``X`` refers to "the next sampling instant" of the robot, which the
    planner and the controller choose, not the user: a continuous trajectory has no next
    position. The translator still accepts ``X`` for automata-theoretic use.
    """
    if not uses_next(f):
        return
    column = None
    if text:
        from planner.ltl.parser import tokenize

        for token in tokenize(text):
            if token.kind == "X":
                column = token.column
                break
    raise FormulaError(
        "the next operator X is not allowed in a mission: a robot moving in continuous space "
        "has no 'next position' (its sampling rate would decide what X means); "
        "use <> (eventually) or U (until) instead",
        formula=text,
        column=column,
        expected="a formula without X",
    )
