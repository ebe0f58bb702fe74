"""Truncated NBA: unrealisable cubes and useless states go, the realisable language stays."""

from __future__ import annotations

import itertools
import random

from planner.ltl.guard import Cube
from planner.ltl.prune import has_accepting_run, prune
from planner.ltl.translate import translate

L = frozenset
GOALS = ("g1", "g2", "g3")


def disjoint_regions(cube: Cube) -> bool:
    """A world whose goal regions are pairwise disjoint and whose obstacles are forbidden."""
    return "o" not in cube.pos and len(cube.pos & set(GOALS)) <= 1


def realisable_letters() -> list[frozenset[str]]:
    return [L()] + [L({g}) for g in GOALS]


def test_pruning_drops_simultaneous_goals_and_keeps_the_language() -> None:
    nba = translate("[]!o && <>g1 && <>g2 && <>g3")
    small = prune(nba, disjoint_regions)
    assert small.num_transitions < nba.num_transitions
    assert small.num_states <= nba.num_states
    assert has_accepting_run(small)
    for e in small.edges:
        assert all(disjoint_regions(c) for c in e.guard.cubes)
    rng = random.Random(5)
    letters = realisable_letters()
    for _ in range(300):
        prefix = [rng.choice(letters) for _ in range(rng.randint(0, 5))]
        cycle = [rng.choice(letters) for _ in range(rng.randint(1, 4))]
        assert small.accepts_lasso(prefix, cycle) == nba.accepts_lasso(prefix, cycle)


def test_sequence_after_pruning_has_one_path_per_goal_order() -> None:
    nba = prune(translate("[]!o && <>(g1 && <>(g2 && <>g3))"), disjoint_regions)
    assert nba.num_states == 4
    # Each waiting state keeps "stay" and "advance by one goal"; the final state keeps "stay".
    assert nba.num_transitions == 7
    assert nba.initial == 0 and nba.state_names[0] == "init"


def test_unrealisable_tasks_have_no_accepting_run() -> None:
    for text in ("<>(g1 && g2)", "[]<>o", "[]!o && <>(o && g1)", "false"):
        pruned = prune(translate(text), disjoint_regions)
        assert not has_accepting_run(pruned)
        assert pruned.num_states == 1  # only the initial state is kept
        assert not pruned.accepts_lasso([], [L()])


def test_has_accepting_run_on_unpruned_automata() -> None:
    assert has_accepting_run(translate("[]<>g1 && []<>g2"))
    assert has_accepting_run(translate("true"))
    assert not has_accepting_run(translate("false"))
    assert not has_accepting_run(translate("a && !a"))


def test_realisability_is_asked_once_per_cube() -> None:
    asked: list[Cube] = []

    def counting(cube: Cube) -> bool:
        asked.append(cube)
        return disjoint_regions(cube)

    nba = translate("[]!o && []<>g1 && []<>g2 && []<>g3")
    prune(nba, counting)
    distinct = {c for e in nba.edges for c in e.guard.cubes}
    assert sorted(asked, key=Cube.sort_key) == sorted(distinct, key=Cube.sort_key)


def test_pruned_recurrence_still_accepts_every_goal_order() -> None:
    nba = prune(translate("[]!o && []<>g1 && []<>g2 && []<>g3"), disjoint_regions)
    assert has_accepting_run(nba)
    for order in itertools.permutations(GOALS):
        assert nba.accepts_lasso([L()], [L({g}) for g in order])
    assert not nba.accepts_lasso([L()], [L({"g1"}), L({"g2"})])
