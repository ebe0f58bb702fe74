"""What every product tree of a TL-RRT* run keeps true, through floods, rewiring and the
suffix trees seeded from the prefix tree's roadmap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.geometry.shapes import Ball
from planner.geometry.world import World
from planner.ltl.translate import translate
from planner.search.planner_spec import REFINE_NODES_PER_ITERATION, PlannerSpec
from planner.search.point_index import PointIndex
from planner.search.product_tree import ProductTree
from planner.search.tl_rrt_star import _Planner
from tests.planner.test_tl_rrt_star import START, world_2d


def _ids(index: PointIndex) -> list[int]:
    return sorted(index.within(np.zeros(index.dim), math.inf).tolist())


def assert_consistent(tree: ProductTree) -> None:
    nodes = tree.num_nodes
    pts = np.array(tree.node_pt)
    qs = np.array(tree.node_q)
    assert (tree.node_at[pts, qs] == np.arange(nodes)).all()
    assert (tree.node_at[: tree.npts] >= 0).sum() == nodes
    for nid in range(nodes):
        parent = tree.parent[nid]
        if parent < 0:
            assert nid in tree.roots and tree.cost[nid] == 0.0
            continue
        assert nid in tree.children[parent]
        step = float(np.linalg.norm(tree.pos[pts[nid]] - tree.pos[pts[parent]]))
        assert tree.cost[nid] == pytest.approx(tree.cost[parent] + step, abs=1e-9)
    assert sum(len(c) for c in tree.children) == nodes - len(tree.roots)
    carrying = np.flatnonzero((tree.node_at[: tree.npts] >= 0).any(axis=1))
    assert _ids(tree.reached) == carrying.tolist()
    entered = 0
    for pid in carrying.tolist():
        entered |= tree.mask[pid]
    assert tree.entered == entered
    for q, layer in tree.layers.items():
        assert _ids(layer) == np.flatnonzero(tree.node_at[: tree.npts, q] >= 0).tolist()


def test_every_tree_of_a_patrol_stays_consistent() -> None:
    spec = PlannerSpec(seed=4, refine_iterations=300)
    nba = translate("[]<>a && []<>b && []<>c && [](!d)")
    planner = _Planner(world_2d(), nba, START, 0.1, spec, np.random.default_rng(4))
    planner.run()
    assert planner.suffixes, "the patrol needs suffix trees"
    for tree in [planner.prefix.tree, *(s.tree for s in planner.suffixes)]:
        assert_consistent(tree)


def test_points_added_together_answer_as_added_one_by_one() -> None:
    rng = np.random.default_rng(0)
    xs = rng.uniform(0, 10, (3000, 2))
    ids = rng.permutation(5000)[:3000]
    one, many = PointIndex(2), PointIndex(2)
    for pid, x in zip(ids[:100], xs[:100], strict=True):
        one.add(int(pid), x)
    many.add_many(ids[:100], xs[:100])
    for pid, x in zip(ids[100:], xs[100:], strict=True):
        one.add(int(pid), x)
    for start in range(100, 3000, 700):  # batches that cross several rebuilds
        many.add_many(ids[start : start + 700], xs[start : start + 700])
    for q in rng.uniform(-1, 11, (200, 2)):
        assert one.nearest(q) == many.nearest(q)
        assert one.within(q, 0.7).tolist() == many.within(q, 0.7).tolist()
        assert one.within(q, 2.0, k=9).tolist() == many.within(q, 2.0, k=9).tolist()


def test_the_anytime_budget_ends_at_its_product_nodes_on_an_any_order_task() -> None:
    """Seven goals in any order: 128 automaton states, each iteration lifts its point onto
    many of them; the budget of 200 iterations ends at 40 new nodes per iteration first."""
    goals = {f"g{i}": Ball(np.array([1.0 + 1.2 * i, 9.0 - (i % 2) * 7.0]), 0.4) for i in range(7)}
    world = World(np.array([[0.0, 10.0], [0.0, 10.0]]), [], goals)
    nba = translate(" && ".join(f"<>{name}" for name in goals))
    assert nba.num_states == 128
    spec = PlannerSpec(seed=0)
    planner = _Planner(world, nba, np.array([5.0, 5.0]), 0.1, spec, np.random.default_rng(0))
    planner.first_lasso()
    nodes, iterations = planner.prefix.tree.num_nodes, planner.prefix.iterations
    planner.refine(0.0, 200)
    grown = planner.prefix.tree.num_nodes - nodes
    assert planner.prefix.iterations - iterations < 200
    assert grown >= 200 * REFINE_NODES_PER_ITERATION
    assert_consistent(planner.prefix.tree)


def _any_order_tree(goals: int = 5) -> ProductTree:
    """The prefix tree of an any-order visit of ``goals`` goals: many states per point."""
    world = World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [],
        {f"g{i}": Ball(np.array([1.0 + 1.6 * i, 9.0 - (i % 2) * 7.0]), 0.4) for i in range(goals)},
    )
    nba = translate(" && ".join(f"<>g{i}" for i in range(goals)))
    spec = PlannerSpec(seed=3)
    planner = _Planner(world, nba, np.array([5.0, 5.0]), 0.1, spec, np.random.default_rng(3))
    planner.first_lasso()
    planner.refine(0.0, 60)
    return planner.prefix.tree


def test_the_nodes_of_a_new_point_made_in_bulk_give_the_tree_made_one_by_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    bulk = _any_order_tree()
    assert_consistent(bulk)

    def one_by_one(
        tree: ProductTree, pid: int, qs: np.ndarray, parents: np.ndarray, costs: np.ndarray
    ) -> list[int]:
        return [
            tree.add_node(pid, q, parent, cost)
            for q, parent, cost in zip(qs.tolist(), parents.tolist(), costs.tolist(), strict=True)
        ]

    monkeypatch.setattr(ProductTree, "_add_at_new_point", one_by_one)
    single = _any_order_tree()
    assert bulk.num_nodes > 4 * bulk.npts  # several states per point
    assert bulk.node_pt == single.node_pt and bulk.node_q == single.node_q
    assert bulk.parent == single.parent and bulk.children == single.children
    assert bulk.cost[: bulk.num_nodes].tolist() == single.cost[: single.num_nodes].tolist()
    for q, layer in bulk.layers.items():
        assert _ids(layer) == _ids(single.layers[q])
