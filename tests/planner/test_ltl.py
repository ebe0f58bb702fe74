"""LTL parser (both syntaxes, precedence, error columns), NNF, spin output, semantics."""

from __future__ import annotations

import random

import pytest

from planner.errors import FormulaError
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
    check_mission_formula,
    children,
    parse,
    to_nnf,
    to_spin,
    to_text,
    uses_next,
)
from planner.ltl.rewrite import simplify
from planner.ltl.semantics import holds_on_lasso
from tests.planner.ltl_random import random_formula, random_lasso

a, b, c = Prop("a"), Prop("b"), Prop("c")


@pytest.mark.parametrize(
    ("spin", "letters"),
    [
        ("[]<>a", "G F a"),
        ("[]<>a", "GFa"),
        ("[]!o && <>(g1 && <>g2)", "G ~o & F (g1 & F g2)"),
        ("a V b", "a R b"),
        ("a /\\ b \\/ c", "a & b | c"),
        ("!(a -> b) <-> X c", "~(a -> b) <-> X c"),
        ("true U false", "true U false"),
    ],
)
def test_both_syntaxes_give_the_same_tree(spin: str, letters: str) -> None:
    assert parse(spin) == parse(letters)


@pytest.mark.parametrize(
    ("text", "tree"),
    [
        ("a && b U c", And(a, Until(b, c))),
        ("!a U b", Until(Not(a), b)),
        ("[]a U b", Until(Globally(a), b)),
        ("a U b U c", Until(a, Until(b, c))),
        ("a R b W c", Release(a, WeakUntil(b, c))),
        ("a || b && c", Or(a, And(b, c))),
        ("a && b && c", And(And(a, b), c)),
        ("a -> b -> c", Implies(a, Implies(b, c))),
        ("a <-> b -> c", Iff(a, Implies(b, c))),
        ("a || b -> c", Implies(Or(a, b), c)),
        ("X !a", Next(Not(a))),
        ("(a || b) && c", And(Or(a, b), c)),
        ("<>[]a", Eventually(Globally(a))),
        ("true && false", And(Const(True), Const(False))),
        ("g_1 && obstacle2", And(Prop("g_1"), Prop("obstacle2"))),
    ],
)
def test_precedence_and_associativity(text: str, tree: Formula) -> None:
    assert parse(text) == tree


@pytest.mark.parametrize(
    ("text", "column", "needle"),
    [
        ("[]!o &&", 8, "expected a formula after '&&', found end of input"),
        ("a && || b", 6, "expected a formula after '&&', found '||'"),
        ("", 1, "expected a formula, found end of input"),
        ("(a || b", 8, "expected ')' to close the '(' at column 1, found end of input"),
        ("a b", 3, "expected an operator or end of input, found 'b'"),
        ("a)", 2, "has no matching '('"),
        ("a $ b", 3, "unexpected character '$'"),
        ("a <- b", 3, "'<>' (eventually) or '<->'"),
        ("Home", 1, "unexpected character 'H'"),
        ("A && b", 1, "propositions are lowercase"),
        ("1 && a", 1, "unexpected character '1'"),
        ("[] (a U)", 8, "expected a formula after 'U', found ')'"),
    ],
)
def test_syntax_errors_name_column_and_expectation(text: str, column: int, needle: str) -> None:
    with pytest.raises(FormulaError) as info:
        parse(text)
    assert info.value.column == column
    assert needle in str(info.value)
    assert f"column {column}:" in str(info.value)


def test_uppercase_operator_letters_are_always_operators() -> None:
    # As in Spot: "GFa" is G F a, so "Goal" reads as G oal (and the world will not know "oal").
    assert parse("GFa") == Globally(Eventually(a))
    assert parse("Goal") == Globally(Prop("oal"))
    assert parse("aUb") == Until(a, b)


def test_error_carries_the_expected_item() -> None:
    with pytest.raises(FormulaError) as info:
        parse("a &&")
    assert info.value.expected == "a formula"
    assert info.value.formula == "a &&"


def test_atoms_and_uses_next() -> None:
    f = parse("[]!obstacle && <>(g1 U X g2)")
    assert atoms(f) == frozenset({"obstacle", "g1", "g2"})
    assert uses_next(f)
    assert not uses_next(parse("[]<>g1 && a W b"))
    assert children(parse("a U b")) == (a, b)


def test_mission_check_rejects_next_with_its_column() -> None:
    text = "[]!o && <>(g1 && X g2)"
    with pytest.raises(FormulaError) as info:
        check_mission_formula(parse(text), text)
    assert info.value.column == 18
    assert "continuous space" in str(info.value)
    check_mission_formula(parse("[]!o && []<>g1"), "[]!o && []<>g1")


def _is_nnf(f: Formula) -> bool:
    if isinstance(f, Not):
        return isinstance(f.arg, Prop)
    if isinstance(f, Implies | Iff):
        return False
    return all(_is_nnf(child) for child in children(f))


def test_nnf_spin_text_and_rewriting_preserve_meaning() -> None:
    rng = random.Random(7)
    for _ in range(300):
        f = random_formula(rng)
        nnf = to_nnf(f)
        assert _is_nnf(nnf)
        variants = [nnf, simplify(nnf), parse(to_spin(f)), parse(to_text(f))]
        for _ in range(10):
            prefix, cycle = random_lasso(rng)
            expected = holds_on_lasso(f, prefix, cycle)
            for g in variants:
                assert holds_on_lasso(g, prefix, cycle) == expected, (to_text(f), to_text(g))


def test_to_spin_uses_spin_operators() -> None:
    text = to_spin(parse("G (a R b) & (a W b) & F X c"))
    assert "V" in text and "[]" in text and "<>" in text and "X" in text
    assert "R" not in text and "W" not in text and "G" not in text and "F" not in text


def test_rewriting_rules() -> None:
    assert simplify(to_nnf(parse("F F a"))) == Eventually(a)
    assert simplify(to_nnf(parse("G G a"))) == Globally(a)
    assert simplify(to_nnf(parse("true U a"))) == Eventually(a)
    assert simplify(to_nnf(parse("false R a"))) == Globally(a)
    assert simplify(to_nnf(parse("a && !a"))) == Const(False)
    gf = simplify(to_nnf(parse("G F a & G F b")))
    assert gf == And(Globally(Eventually(a)), Globally(Eventually(b)))
    assert simplify(to_nnf(parse("G (F a & F b)"))) == gf
    assert simplify(to_nnf(parse("G F (a & F b)"))) == gf
    assert simplify(to_nnf(parse("G F X (a & F b)"))) == gf
    assert simplify(to_nnf(parse("G F a | G F b"))) == Globally(Eventually(Or(a, b)))


L = frozenset


@pytest.mark.parametrize(
    ("text", "prefix", "cycle", "expected"),
    [
        ("G F a", [L()], [L(), L({"a"})], True),
        ("G F a", [L({"a"})], [L()], False),
        ("F G a", [L()], [L({"a"})], True),
        ("F G a", [L({"a"})], [L(), L({"a"})], False),
        ("a U b", [L({"a"}), L({"a"})], [L({"b"})], True),
        ("a U b", [L({"a"}), L()], [L({"b"})], False),
        ("a W b", [L({"a"})], [L({"a"})], True),
        ("a U b", [L({"a"})], [L({"a"})], False),
        ("a R b", [L({"b"})], [L({"b"})], True),
        ("a R b", [L({"b"}), L({"a", "b"})], [L()], True),
        ("a R b", [L({"b"}), L({"a"})], [L()], False),
        ("X a", [L()], [L({"a"})], True),
        ("X X a", [L(), L({"a"})], [L()], False),
        ("G (a -> X b)", [L({"a"})], [L({"b"}), L({"a"})], True),
        ("G (a -> X b)", [L({"a"})], [L({"a"}), L()], False),
        ("(a <-> b) && !false", [L({"a", "b"})], [L()], True),
    ],
)
def test_lasso_semantics(
    text: str, prefix: list[frozenset[str]], cycle: list[frozenset[str]], expected: bool
) -> None:
    assert holds_on_lasso(parse(text), prefix, cycle) is expected


def test_lasso_semantics_needs_a_cycle() -> None:
    with pytest.raises(ValueError, match="cycle"):
        holds_on_lasso(a, [L()], [])
