"""Cutting lassos into sub-tasks: goals, merging, chaining and phases."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from planner.decompose import SubTask, decompose, lasso_stages, subtask_at
from planner.geometry.shapes import Ball, Box
from planner.geometry.world import World
from planner.ltl.automaton import Buchi, Edge
from planner.ltl.guard import Cube, Guard
from planner.ltl.translate import translate
from planner.plan import plan_mission, verify_plan
from planner.search.planner_spec import PlannerSpec
from planner.search.tl_rrt_star import Lasso, make_lasso, plan_lasso

TRUE = Guard.TRUE


def lit(name: str, positive: bool = True) -> Guard:
    return Guard.literal(name, positive)


def both(*names: str) -> Guard:
    return Guard.of([Cube(frozenset(names), frozenset())])


def automaton(edges: list[tuple[int, Guard, int]], accepting: set[int], n: int) -> Buchi:
    return Buchi(
        atoms=("a", "b"),
        state_names=tuple(f"s{i}" for i in range(n)),
        initial=0,
        accepting=frozenset(accepting),
        edges=tuple(Edge(s, g, t) for s, g, t in edges),
    )


def line_world(overlap: bool = False) -> World:
    a = Box(np.array([1.0, -1.0]), np.array([3.0 if overlap else 2.0, 1.0]))
    b = Box(np.array([2.0 if overlap else 4.0, -1.0]), np.array([5.0, 1.0]))
    return World(np.array([[-1.0, 7.0], [-3.0, 5.0]]), [], {"a": a, "b": b})


def lasso(
    prefix: list[list[float]], pq: list[int], suffix: list[list[float]], sq: list[int]
) -> Lasso:
    return make_lasso(np.array(prefix), np.array(suffix), pq, sq, 0.2)


def check_chain(subs: list[SubTask], las: Lasso, world: World) -> None:
    assert [s.index for s in subs] == list(range(len(subs)))
    phases = [s.phase for s in subs]
    assert phases == sorted(phases, key=["prefix", "suffix"].index)
    for phase, path in (("prefix", las.prefix), ("suffix", las.suffix)):
        mine = [s for s in subs if s.phase == phase]
        if not mine:
            assert len(path) == 1 or np.allclose(path, path[0])
            continue
        joined = np.vstack([mine[0].path] + [s.path[1:] for s in mine[1:]])
        np.testing.assert_allclose(joined, path)
        for s in mine:
            np.testing.assert_allclose(s.start, s.path[0])
            assert np.linalg.norm(np.diff(s.path, axis=0), axis=1).sum() > 0
            if s.goal:
                assert s.goal in world.labels(s.path[-1])


def test_sequential_goals() -> None:
    nba = automaton(
        [(0, TRUE, 0), (0, lit("a"), 1), (1, TRUE, 1), (1, lit("b"), 2), (2, TRUE, 2)], {2}, 3
    )
    world = line_world()
    las = lasso([[0, 0], [0.5, 0], [1.5, 0], [3, 0], [4.5, 0]], [0, 0, 1, 1, 2], [[4.5, 0]], [2])
    subs = decompose(las, nba, world)
    assert [(s.goal, s.phase, s.nba_state, s.next_nba_state) for s in subs] == [
        ("a", "prefix", 0, 1),
        ("b", "prefix", 1, 2),
    ]
    np.testing.assert_allclose(subs[0].path, np.array([[0, 0], [0.5, 0], [1.5, 0]], dtype=float))
    np.testing.assert_allclose(subs[1].path, np.array([[1.5, 0], [3, 0], [4.5, 0]], dtype=float))
    check_chain(subs, las, world)


def test_goal_is_the_region_entered_when_several_hold() -> None:
    nba = automaton([(0, TRUE, 0), (0, both("a", "b"), 1), (1, TRUE, 1)], {1}, 2)
    world = line_world(overlap=True)
    las = lasso([[0, 0], [1.5, 0], [2.5, 0]], [0, 0, 1], [[2.5, 0]], [1])
    subs = decompose(las, nba, world)
    assert [(s.goal, s.nba_state, s.next_nba_state) for s in subs] == [("b", 0, 1)]
    # entering both at once: the alphabetically first of the enabling regions
    las = lasso([[0, 0], [2.5, 0]], [0, 1], [[2.5, 0]], [1])
    assert [s.goal for s in decompose(las, nba, world)] == ["a"]


def test_transition_on_leaving_is_merged_into_the_next_piece() -> None:
    # a U (!a && <>b): the automaton moves when the robot leaves a
    nba = automaton(
        [(0, lit("a"), 0), (0, lit("a", False), 1), (1, TRUE, 1), (1, lit("b"), 2), (2, TRUE, 2)],
        {2},
        3,
    )
    world = line_world()
    las = lasso([[1.5, 0], [2.5, 0], [3.5, 0], [4.5, 0]], [0, 1, 1, 2], [[4.5, 0]], [2])
    subs = decompose(las, nba, world)
    assert [(s.goal, s.nba_state, s.next_nba_state) for s in subs] == [("b", 0, 2)]
    check_chain(subs, las, world)
    # when the leaving transition ends the phase there is no region: the goal is the path end
    las = lasso([[1.5, 0], [2.5, 0]], [0, 1], [[2.5, 0]], [1])
    nba_leave = automaton([(0, lit("a"), 0), (0, lit("a", False), 1), (1, TRUE, 1)], {1}, 2)
    assert [s.goal for s in decompose(las, nba_leave, world)] == [""]


def test_suffix_cycle_and_degenerate_pieces() -> None:
    # GF a && GF b, hand-made: 2 is accepting after b, 0 waits for a
    nba = automaton(
        [
            (0, TRUE, 0),
            (0, lit("a"), 1),
            (1, TRUE, 1),
            (1, lit("b"), 2),
            (2, TRUE, 0),
            (2, lit("a"), 1),
        ],
        {2},
        3,
    )
    world = line_world()
    prefix: list[list[float]] = [[0, 0], [1.5, 0], [1.5, 0], [3, 0], [4.5, 0]]
    suffix: list[list[float]] = [[4.5, 0], [3, 0.5], [1.5, 0.5], [3, 0], [4.5, 0]]
    las = lasso(prefix, [0, 0, 1, 1, 2], suffix, [2, 0, 1, 1, 2])
    subs = decompose(las, nba, world)
    got = [(s.phase, s.goal, s.nba_state, s.next_nba_state) for s in subs]
    assert got == [
        ("prefix", "a", 0, 1),
        ("prefix", "b", 1, 2),
        ("suffix", "a", 2, 1),
        ("suffix", "b", 1, 2),
    ]
    np.testing.assert_allclose(subs[0].path, np.array([[0, 0], [1.5, 0], [1.5, 0]], dtype=float))
    np.testing.assert_allclose(subs[2].start, [4.5, 0])
    check_chain(subs, las, world)


def test_one_point_prefix_and_suffix_have_no_subtasks() -> None:
    nba = automaton([(0, TRUE, 0), (0, lit("a"), 1), (1, TRUE, 1)], {1}, 2)
    las = lasso([[1.5, 0]], [1], [[1.5, 0]], [1])
    assert decompose(las, nba, line_world()) == []


@pytest.mark.parametrize(
    "task",
    ["[]!obstacle && <>(g1 && <>(g2 && <>g3))", "[]<>g1 && []<>(g2 || g3) && []!g4"],
)
def test_planned_lassos_decompose_into_chained_goal_reaching_subtasks(task: str) -> None:
    world = World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [Box(np.array([4.0, 2.0]), np.array([6.0, 8.0]))],
        {
            "g1": Ball(np.array([1.0, 9.0]), 0.7),
            "g2": Box(np.array([8.0, 8.0]), np.array([9.5, 9.5])),
            "g3": Ball(np.array([9.0, 1.0]), 0.7),
            "g4": Box(np.array([2.0, 4.0]), np.array([3.0, 6.0])),
        },
    )
    nba = translate(task)
    las = plan_lasso(world, nba, np.array([1.0, 1.0]), 0.1, PlannerSpec(seed=3, refine_seconds=0))
    subs = decompose(las, nba, world)
    check_chain(subs, las, world)
    assert all(s.goal for s in subs)
    assert subs[0].nba_state == las.prefix_states[0]
    for prev, nxt in itertools.pairwise(subs):
        if prev.phase == nxt.phase:
            assert prev.next_nba_state == nxt.nba_state
    if len(las.suffix) == 1:
        assert all(s.phase == "prefix" for s in subs)
    else:
        assert any(s.phase == "suffix" for s in subs)


def test_zero_length_piece_is_merged() -> None:
    nba = automaton(
        [(0, TRUE, 0), (0, lit("a"), 1), (1, TRUE, 1), (1, lit("b"), 2), (2, TRUE, 2)], {2}, 3
    )
    world = line_world(overlap=True)
    # a and b are entered together: two automaton moves at the same point
    las = lasso([[0, 0], [2.5, 0], [2.5, 0]], [0, 1, 2], [[2.5, 0]], [2])
    subs = decompose(las, nba, world)
    assert [(s.goal, s.nba_state, s.next_nba_state) for s in subs] == [("a", 0, 2)]
    check_chain(subs, las, world)
    las = lasso([[0, 0], [2.5, 0], [2.5, 0], [4.5, 0]], [0, 1, 2, 2], [[4.5, 0]], [2])
    subs = decompose(las, nba, world)
    assert [(s.goal, s.nba_state, s.next_nba_state) for s in subs] == [("a", 0, 1), ("b", 1, 2)]
    check_chain(subs, las, world)


def test_lasso_order_runs_the_prefix_once_then_cycles_the_suffix() -> None:
    point = np.zeros((1, 2))
    phases = ["prefix", "prefix", "suffix", "suffix"]
    subs = [SubTask(i, p, "", point[0], point, 0, 0) for i, p in enumerate(phases)]  # type: ignore[arg-type]
    assert lasso_stages(subs, 2) == [0, 1, 2, 3, 2, 3]
    assert lasso_stages(subs, 0) == [0, 1]
    assert [subtask_at(subs, n) for n in range(7)] == [0, 1, 2, 3, 2, 3, 2]
    finite = subs[:2]
    assert [subtask_at(finite, n) for n in range(4)] == [0, 1, 1, 1]


def path_length(path: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())


def test_long_sub_tasks_are_cut_into_chained_legs_of_at_most_the_leg_length() -> None:
    world = World(
        np.array([[0.0, 20.0], [0.0, 10.0]]),
        [Box(np.array([9.0, 0.0]), np.array([11.0, 7.0]))],
        {"g1": Ball(np.array([18.5, 1.5]), 0.8), "g2": Ball(np.array([1.5, 8.5]), 0.8)},
    )
    task, start = "[]<>g1 && []<>g2", np.array([1.0, 1.0])
    whole = plan_mission(world, task, start, 0.3, PlannerSpec(seed=2))
    legged = plan_mission(world, task, start, 0.3, PlannerSpec(seed=2, leg_length=4.0))
    assert verify_plan(legged, world, 0.3) == []
    assert [s.index for s in legged.subtasks] == list(range(len(legged.subtasks)))
    assert len(legged.subtasks) > len(whole.subtasks)
    legs = iter(legged.subtasks)
    for sub in whole.subtasks:
        count = math.ceil(path_length(sub.path) / 4.0 - 1e-9)
        mine = [next(legs) for _ in range(count)]
        assert all(leg.phase == sub.phase for leg in mine)
        assert all(path_length(leg.path) <= 4.0 + 1e-9 for leg in mine)
        assert sum(path_length(leg.path) for leg in mine) == pytest.approx(path_length(sub.path))
        np.testing.assert_allclose(mine[0].start, sub.start)
        np.testing.assert_allclose(mine[-1].path[-1], sub.path[-1])
        for a, b in itertools.pairwise(mine):
            np.testing.assert_allclose(a.path[-1], b.start)
            assert (a.goal, a.nba_state, a.next_nba_state) == ("", sub.nba_state, sub.nba_state)
        assert (mine[-1].goal, mine[-1].next_nba_state) == (sub.goal, sub.next_nba_state)
    assert next(legs, None) is None
    first, second, *rest = legged.subtasks
    assert first.goal == "" and second.phase == first.phase
    off = first.path[-1] + np.array([0.0, 0.01])
    bent = [
        dataclasses.replace(first, path=np.vstack([first.path[:-1], off])),
        dataclasses.replace(second, start=off, path=np.vstack([off, second.path[1:]])),
        *rest,
    ]
    problems = verify_plan(dataclasses.replace(legged, subtasks=bent), world, 0.3)
    assert "the prefix sub-task paths do not chain into the prefix" in problems
