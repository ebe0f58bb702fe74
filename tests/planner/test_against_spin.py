"""Our translator against an independent one (spin) and the direct lasso semantics.

For a few hundred seeded random formulas over {a, b, c} and 30 random lasso words each,
our automaton, spin's never claim and :func:`holds_on_lasso` must agree on every word.
The spin packaged by Debian is built without ``X``; formulas using ``X`` are checked
against the semantics only (and counted). Spin is slow on a few formulas: those that take
over 10 s are skipped and counted, and must stay a small fraction.
"""

from __future__ import annotations

import random
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

from planner.ltl.formula import Formula, to_spin, to_text, uses_next
from planner.ltl.semantics import holds_on_lasso
from planner.ltl.translate import translate
from tests.planner.ltl_random import PROPS, random_formula, random_lasso
from tests.planner.spin_claim import parse_claim, parse_condition, reachable_states, run_spin

FORMULAS = 300
WORDS = 30
SPIN_TIMEOUT = 10.0

needs_spin = pytest.mark.skipif(shutil.which("spin") is None, reason="spin is not installed")


def _spin_claim(formula: Formula) -> str | None:
    try:
        return run_spin(to_spin(formula), timeout=SPIN_TIMEOUT)
    except subprocess.TimeoutExpired:
        return None


@needs_spin
def test_translator_agrees_with_spin_and_semantics() -> None:
    rng = random.Random(20240521)
    formulas = [
        random_formula(rng, depth=4, allow_next=rng.random() < 0.4) for _ in range(FORMULAS)
    ]
    with_spin = [f for f in formulas if not uses_next(f)]
    # Two workers: spin runs in a separate process, and a few formulas take seconds.
    with ThreadPoolExecutor(max_workers=2) as pool:
        claims = dict(zip(with_spin, pool.map(_spin_claim, with_spin), strict=True))
    skipped = sum(1 for claim in claims.values() if claim is None)
    compared = 0
    for f in formulas:
        ours = translate(f)
        claim = claims.get(f)
        theirs = parse_claim(claim, PROPS) if claim is not None else None
        compared += theirs is not None
        for _ in range(WORDS):
            prefix, cycle = random_lasso(rng)
            truth = holds_on_lasso(f, prefix, cycle)
            context = (to_text(f), prefix, cycle, truth)
            assert ours.accepts_lasso(prefix, cycle) == truth, context
            if theirs is not None:
                assert theirs.accepts_lasso(prefix, cycle) == truth, ("spin", *context)
    print(
        f"\n{len(formulas)} formulas x {WORDS} words: {compared} compared with spin, "
        f"{len(formulas) - len(with_spin)} with X (semantics only), {skipped} spin timeouts"
    )
    assert skipped <= 0.05 * len(with_spin), f"spin timed out on {skipped} formulas"
    assert compared >= 0.6 * len(formulas)


@needs_spin
def test_our_automata_are_never_larger_than_spins() -> None:
    rng = random.Random(99)
    larger = []
    for _ in range(60):
        f = random_formula(rng, depth=3, allow_next=False)
        claim = _spin_claim(f)
        if claim is None:
            continue
        spin_states = reachable_states(parse_claim(claim, PROPS))
        if translate(f).num_states > spin_states:
            larger.append(to_text(f))
    assert not larger


CLAIM = """never  {    /* []<>a && []<>b */
T0_init:
\tdo
\t:: ((a) && (b)) -> goto accept_S81
\t:: ((a)) -> goto T1_S81
\t:: (1) -> goto T0_init
\tod;
accept_S81:
\tdo
\t:: (1) -> goto T0_init
\tod;
T1_S81:
\tdo
\t:: ((b)) -> goto accept_S81
\t:: (1) -> goto T1_S81
\tod;
}
"""

SHORTCUT = """never  {    /* a U b */
T0_init:
\tdo
\t:: atomic { ((b)) -> assert(!((b))) }
\t:: ((a)) -> goto T0_init
\tod;
accept_S3:
\tdo
\t:: false
\tod;
accept_all:
\tskip
}
"""

L = frozenset


def test_claim_parser_reads_states_labels_and_shortcuts() -> None:
    gf = parse_claim(CLAIM, ("a", "b"))
    assert gf.state_names == ("T0_init", "accept_S81", "T1_S81", "accept_all")
    assert reachable_states(gf) == 3
    assert gf.accepts_lasso([], [L({"a"}), L({"b"})])
    assert not gf.accepts_lasso([], [L({"a"})])
    until = parse_claim(SHORTCUT, ("a", "b"))
    assert until.initial not in until.accepting
    assert until.accepts_lasso([L({"a"}), L({"a"})], [L({"b"}), L()])
    assert not until.accepts_lasso([L({"a"})], [L({"a"})])
    assert not until.out_edges(until.state_names.index("accept_S3"))


ALIASES = """never  {    /* []a */
accept_init:
T0_init:
\tdo
\t:: ((a)) -> goto T0_init
\tod;
}
"""


def test_claim_parser_merges_labels_of_one_state() -> None:
    always = parse_claim(ALIASES, ("a",))
    assert always.num_states == 2  # the state and the (unused) accepting sink
    assert always.initial in always.accepting
    assert always.accepts_lasso([], [L({"a"})])
    assert not always.accepts_lasso([L({"a"})], [L()])


def test_claim_conditions() -> None:
    g = parse_condition("(! ((b)) && ((a) || (true || c))) || (false)")
    for letter in (L(), L({"a"}), L({"b"}), L({"a", "b", "c"})):
        assert g.holds(letter) == ("b" not in letter)
