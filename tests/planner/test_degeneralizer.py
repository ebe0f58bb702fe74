"""The degeneralizer's states as its automaton names them."""

from __future__ import annotations

from planner.ltl.formula import parse, to_nnf
from planner.ltl.gba import Degeneralizer
from planner.ltl.rewrite import simplify
from planner.ltl.vwaa import build_vwaa


def test_each_state_is_named_by_its_formulas_and_level() -> None:
    degeneralizer = Degeneralizer(build_vwaa(simplify(to_nnf(parse("G F a & G F b")))))
    built = degeneralizer.build()
    states = [state for state in built.names if isinstance(state, tuple)]
    assert len(states) == built.num_states  # one initial set: no extra initial state
    described = [degeneralizer.describe(state) for state in states]
    assert described[built.initial] == "{G F a & G F b}/0"
    assert sorted(set(described)) == sorted(described)  # one state per set and level
    accepting = {described[q] for q in built.accepting}
    assert accepting == {"{G F a & G F b}/2"}
