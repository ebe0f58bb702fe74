"""TL-RRT*: a lasso plan in the product of the workspace and a Büchi automaton.

After Luo, Kantaros and Zavlanos, "An abstraction-free method for multirobot planning with
temporal logic tasks" (T-RO 2021). A prefix tree rooted at ``(start, q)`` grows by RRT* in the
product space (:mod:`planner.search.product_tree`) until it holds nodes whose automaton state is
accepting and lies on an automaton cycle. For such a node ``(x*, q*)`` a suffix tree rooted at
it grows until one of its nodes can step back to ``(x*, q*)``; the lasso is the prefix branch
followed by that cycle. When ``q*`` loops on the label of ``x*`` (always for a co-safe task,
whose accepting state loops on ``true``), staying at ``x*`` is the cycle: ``suffix = [x*]``.

Sampling is biased as in the paper: with probability ``bias`` the tree extends, from its
nearest node in the automaton state closest to the goal, toward a point of the region whose
label enables the next transition on a shortest automaton path to the goal (acceptance for the
prefix; the states that step back to ``q*`` for the suffix). Otherwise it extends toward a
uniform free point from the nearest node of any state.

Anytime: once a first lasso exists the prefix tree keeps growing for ``refine_iterations``
iterations (bounded in product nodes too), or for ``refine_seconds`` CPU seconds when that is
set (RRT* rewiring shortens branches; more accepting nodes appear), the suffix trees restart
from its grown roadmap (:mod:`planner.search.roadmap`), and the cheapest lasso ``prefix_weight *
prefix + (1 - prefix_weight) * suffix`` is kept; with ``shortcut`` it is then shortened by
:mod:`planner.search.shortcut`, which keeps it a valid product run. With the default iteration
budget the plan depends only on the mission and the seed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from planner.errors import PlanningError, unsatisfiable
from planner.geometry.labels import LabelOracle
from planner.geometry.polyline import path_length
from planner.geometry.world import World
from planner.ltl.automaton import Buchi
from planner.search.growth import Growth, SuffixGrowth
from planner.search.keep_out import keep_out
from planner.search.planner_spec import REFINE_NODES_PER_ITERATION, PlannerSpec
from planner.search.product_sampling import Realisable, Sampler, Stepper
from planner.search.product_tree import ProductTree
from planner.search.shortcut import LassoRun, Ops, polish


@dataclass
class Lasso:
    """A plan ``prefix · suffix^ω``: ``prefix[0]`` is the start, ``suffix[0] == suffix[-1] ==
    prefix[-1]``. ``*_states[i]`` is the automaton state after reading the label of waypoint
    i. ``cost = w * prefix_cost + (1 - w) * suffix_cost`` with ``w = prefix_weight``.
    ``stats`` holds timings (CPU seconds) and tree sizes for benchmarks."""

    prefix: np.ndarray
    suffix: np.ndarray
    prefix_states: list[int]
    suffix_states: list[int]
    prefix_cost: float
    suffix_cost: float
    cost: float
    stats: dict[str, float] = field(default_factory=dict)


def default_eta(world: World) -> float:
    """The default steering step: a twentieth of the workspace diagonal."""
    return world.diagonal / 20.0


class _Planner:
    """State of one TL-RRT* run; :meth:`run` returns the lasso or raises PlanningError."""

    def __init__(
        self,
        world: World,
        nba: Buchi,
        start: np.ndarray,
        clearance: float,
        options: PlannerSpec,
        rng: np.random.Generator,
        lift: bool = True,
        seed: bool = True,
        give_up_cut_off: bool = False,
        hold: float = 0.0,
    ) -> None:
        self.t0 = time.process_time()
        self.seed, self.give_up_cut_off = seed, give_up_cut_off
        self.world, self.nba, self.options, self.clearance = world, nba, options, clearance
        self.hold = max(hold, clearance)
        self.start = np.asarray(start, dtype=float).reshape(-1)
        self.w = options.prefix_weight
        self.paths = Realisable(nba, world, clearance)
        self.acc_dist = self.paths.acceptance_distances()
        if nba.initial not in self.acc_dist:
            raise unsatisfiable(nba.initial in nba.distances_to_acceptance())
        if len(self.start) != world.dim:
            raise PlanningError(f"the start {self.start.tolist()} is not a {world.dim}D point")
        if world.in_collision(self.start[None, :], clearance)[0]:
            raise PlanningError(
                f"the start {self.start.tolist()} is in collision (clearance {clearance})"
            )
        self.eta = options.eta if options.eta is not None else default_eta(world)
        self.oracle = LabelOracle(world, nba.atoms)
        self.stepper = Stepper(nba, self.oracle)
        self.sampler = Sampler(world, self.oracle, rng, clearance, bridge_sigma=self.eta / 2.0)
        d = world.dim
        unit_ball = math.pi ** (d / 2) / math.gamma(d / 2 + 1)
        gamma = 2.0 * (1.0 + 1.0 / d) ** (1.0 / d) * (world.volume / unit_ball) ** (1.0 / d)
        tree = ProductTree(
            world, self.oracle, self.stepper, nba.num_states, clearance, self.eta, gamma, lift
        )
        mask = self.oracle.masks(self.start[None, :])[0]
        roots = [q for q in self.stepper(nba.initial, mask) if q in self.acc_dist]
        if not roots:
            label = sorted(self.oracle.label(mask))
            raise PlanningError(
                f"the task is already violated at the start: its label {label} leaves the "
                "automaton no accepting continuation"
            )
        pid = tree.add_point(self.start, mask)
        for q in roots:
            tree.add_node(pid, q, -1, 0.0)
        self.prefix = Growth(tree, self.paths, self.acc_dist, self.sampler, options.bias)
        self.prefix.goal_nodes.extend(
            n for n in range(tree.num_nodes) if self.acc_dist[tree.node_q[n]] == 0
        )
        self.suffixes: list[SuffixGrowth] = []
        self.trivial: list[int] = []
        self._tried = 0

    def elapsed(self) -> float:
        return time.process_time() - self.t0

    # ----------------------------------------------------------------------------- search
    def _consider_candidates(self, limit: int) -> None:
        """Give new accepting prefix nodes a trivial cycle or (up to ``limit``) a suffix tree."""
        goal = self.prefix.goal_nodes
        tree = self.prefix.tree
        while self._tried < len(goal):
            nid = goal[self._tried]
            self._tried += 1
            q, pid = tree.node_q[nid], tree.node_pt[nid]
            if q in self.stepper(q, tree.mask[pid]):
                self.trivial.append(nid)
                continue
            if len(self.suffixes) >= limit:
                continue
            x = tree.pos[pid]
            spread = 2.0 * self.eta
            if any(np.linalg.norm(s.x_star - x) < spread for s in self.suffixes):
                continue
            self.suffixes.append(
                SuffixGrowth(
                    self.prefix, nid, self.stepper, self.sampler, self.options.bias, self.seed
                )
            )

    def _grow_prefix(self, n: int, until_goal: bool = False) -> None:
        for _ in range(n):
            if self.prefix.iterations >= self.options.max_iterations:
                return
            if self.prefix.step() and until_goal:
                return

    def _grow_suffixes(self, n: int, deadline: float, until_closed: bool = False) -> None:
        """``n`` iterations of each suffix tree; the clock is read once per tree (reading the
        CPU clock costs as much as a cheap iteration)."""
        for s in self.suffixes:
            if math.isfinite(deadline) and self.elapsed() > deadline:
                return
            for _ in range(n):
                if s.iterations >= self.options.max_iterations:
                    break
                s.step()
                if until_closed and s.closers:
                    return

    def first_lasso(self) -> Lasso:
        """Grow until a first lasso exists; PlanningError with the reason when out of budget."""
        limit = self.options.time_limit
        while True:
            self._consider_candidates(limit=4)
            found = self.best_lassos(1)
            if found:
                return found[0]
            exhausted = self.prefix.iterations >= self.options.max_iterations and all(
                s.iterations >= self.options.max_iterations for s in self.suffixes
            )
            if self.elapsed() > limit or exhausted:
                raise PlanningError(self._failure_reason())
            if self.suffixes:
                self._grow_suffixes(100, limit, until_closed=True)
                if not any(s.closers for s in self.suffixes):
                    for s in self.suffixes:
                        s.flood_if_due()
                        s.corridor_if_stuck()
                    self._grow_prefix(10)
            else:
                self._grow_prefix(20, until_goal=True)
                self.prefix.flood_if_due()
                self.prefix.corridor_if_stuck()
                if self.give_up_cut_off and self.prefix.cut_off:
                    raise PlanningError(
                        "the next regions look cut off at this clearance: no path of grid "
                        "cells keeping it joins them to the tree"
                    )

    def refine(self, seconds: float, iterations: int | None = None) -> None:
        """Anytime phase: grow the prefix tree for ``seconds`` CPU seconds, or for
        ``iterations`` iterations (deterministic; or ``REFINE_NODES_PER_ITERATION`` new product
        nodes per iteration); then give new accepting nodes their suffix trees and restart every
        suffix tree from the grown roadmap.

        The suffix trees do not grow meanwhile: the shortest cycle through the prefix tree's
        roadmap (a graph, searched exactly by Dijkstra) was measured as short as the one a
        suffix tree grown alongside reaches, at half the CPU time."""
        deadline = self.elapsed() + seconds
        stop = self.prefix.iterations + iterations if iterations is not None else None
        node_stop = self.prefix.tree.num_nodes + REFINE_NODES_PER_ITERATION * (iterations or 0)
        while (
            self.elapsed() < deadline
            if stop is None
            else self.prefix.iterations < stop and self.prefix.tree.num_nodes < node_stop
        ):
            before = self.prefix.iterations
            self._grow_prefix(30 if stop is None else min(30, stop - before))
            if self.prefix.iterations == before:
                break
        self._consider_candidates(limit=4)
        self._reseed_suffixes()

    def _reseed_suffixes(self) -> None:
        """Give every suffix tree seeded from an older roadmap a fresh start from the prefix
        tree's roadmap, now grown, and keep it where its cycle is cheaper."""
        for i, s in enumerate(self.suffixes):
            if not self.seed or s.roadmap_points == self.prefix.tree.npts:
                continue
            fresh = SuffixGrowth(
                self.prefix, s.prefix_node, self.stepper, self.sampler, self.options.bias
            )
            old, new = s.best_cycle(), fresh.best_cycle()
            if new is not None and (old is None or new[1] < old[1]):
                self.suffixes[i] = fresh

    def best_lassos(self, k: int) -> list[Lasso]:
        """The ``k`` cheapest lassos available from the current trees."""
        tree = self.prefix.tree
        options: list[tuple[float, int, SuffixGrowth | None]] = []
        if self.trivial:
            nid = min(self.trivial, key=lambda n: tree.cost[n])
            options.append((self.w * tree.cost[nid], nid, None))
        for s in self.suffixes:
            cyc = s.best_cycle()
            if cyc is not None:
                cost = self.w * tree.cost[s.prefix_node] + (1 - self.w) * cyc[1]
                options.append((cost, s.prefix_node, s))
        options.sort(key=lambda o: o[0])
        return [self._assemble(nid, s) for _, nid, s in options[:k]]

    def _assemble(self, nid: int, suffix: SuffixGrowth | None) -> Lasso:
        pre, pre_q = self.prefix.tree.branch(nid)
        if suffix is None:
            suf, suf_q = pre[-1:].copy(), [pre_q[-1]]
        else:
            cyc = suffix.best_cycle()
            assert cyc is not None
            suf, suf_q = suffix.tree.branch(cyc[0])
            suf = np.vstack([suf, pre[-1:]])
            suf_q = [*suf_q, pre_q[-1]]
        return make_lasso(pre, suf, pre_q, suf_q, self.w)

    def _failure_reason(self) -> str:
        budget = (
            f"after {self.prefix.iterations} prefix iterations and {self.elapsed():.1f} CPU s "
            "(raise planner.max_iterations / planner.time_limit if the world is large)"
        )
        if not self.prefix.goal_nodes:
            return "no accepting state reached " + budget + ": " + self._stuck(self.prefix)
        reasons = sorted({self._stuck(s) for s in self.suffixes})
        return (
            "an accepting state was reached but no cycle back to it was closed "
            + budget
            + ": "
            + "; ".join(reasons)
        )

    def _stuck(self, growth: Growth) -> str:
        """Why ``growth`` did not reach its goal: the regions it needed but never entered."""
        _, states = growth.closest_states()
        needed: set[str] = set()
        for q in states:
            for cube in self.paths.advancing_cubes(q, growth.dist):
                needed |= cube.pos
        names = self.oracle.names
        never = sorted(
            n for n in needed if n in names and not (growth.tree.entered >> names.index(n)) & 1
        )
        if never:
            empty = sorted(set(never) & self.sampler.empty_regions)
            what = ", ".join(f"region {n}" for n in never)
            note = f" ({', '.join(empty)} has no free point)" if empty else ""
            return f"{what} was never entered{note}; it may be enclosed by obstacles"
        where = ", ".join(self.nba.state_names[q] for q in states) or "?"
        return (
            f"the automaton never advanced past state(s) {where}: the labels that advance it "
            "were reached but not by a collision-free path with at most one label change per "
            "edge"
        )

    # ------------------------------------------------------------------------------- run
    def run(self) -> Lasso:
        first = self.first_lasso()
        t_first = self.elapsed()
        seconds = self.options.refine_seconds
        if first.cost > 0 and seconds is not None and seconds > 0:
            self.refine(seconds)
        elif first.cost > 0 and seconds is None and self.options.refine_iterations > 0:
            self.refine(0.0, self.options.refine_iterations)
        candidates = self.best_lassos(3)
        best = candidates[0]
        if self.options.shortcut:
            polished = [self._polish(c) for c in candidates]
            best = min(polished, key=lambda c: c.cost)
        best = self._keep_out(best)
        best.stats = {
            "first_seconds": t_first,
            "first_cost": first.cost,
            "seconds": self.elapsed(),
            "prefix_iterations": float(self.prefix.iterations),
            "suffix_iterations": float(sum(s.iterations for s in self.suffixes)),
            "prefix_nodes": float(self.prefix.tree.num_nodes),
        }
        return best

    def _polish(self, lasso: Lasso) -> Lasso:
        run = LassoRun(lasso.prefix, lasso.suffix, lasso.prefix_states, lasso.suffix_states, self.w)
        out = polish(run, self.world, self.oracle, self.stepper, self.clearance, self.eta)
        return make_lasso(out.prefix, out.suffix, out.prefix_states, out.suffix_states, self.w)

    def _keep_out(self, lasso: Lasso) -> Lasso:
        """``lasso`` pushed to ``hold`` from the obstacles and to the clearance from the regions
        forbidden where it passes (:mod:`planner.search.keep_out`)."""
        ops = Ops(self.world, self.oracle, self.stepper, self.clearance)
        run = LassoRun(lasso.prefix, lasso.suffix, lasso.prefix_states, lasso.suffix_states, self.w)
        out = keep_out(run, ops, self.nba, self.oracle.names, self.clearance, self.hold)
        if out is run:
            return lasso
        return make_lasso(out.prefix, out.suffix, out.prefix_states, out.suffix_states, self.w)


def make_lasso(
    prefix: np.ndarray,
    suffix: np.ndarray,
    prefix_states: list[int],
    suffix_states: list[int],
    prefix_weight: float,
) -> Lasso:
    """A :class:`Lasso` with its costs computed from the geometry."""
    pc, sc = path_length(prefix), path_length(suffix)
    return Lasso(
        prefix=prefix,
        suffix=suffix,
        prefix_states=list(prefix_states),
        suffix_states=list(suffix_states),
        prefix_cost=pc,
        suffix_cost=sc,
        cost=prefix_weight * pc + (1.0 - prefix_weight) * sc,
    )


def plan_lasso(
    world: World,
    nba: Buchi,
    start: np.ndarray,
    clearance: float,
    options: PlannerSpec,
    rng: np.random.Generator | None = None,
    give_up_cut_off: bool = False,
    hold: float = 0.0,
) -> Lasso:
    """TL-RRT* lasso for the (pruned) automaton ``nba`` from ``start`` in ``world``.

    ``rng`` defaults to ``numpy.random.default_rng(options.seed)``. Raises PlanningError when
    the automaton has no accepting run, or when ``max_iterations`` / ``time_limit`` run out
    without a lasso (the message names the regions never reached). The anytime phase runs for
    ``refine_iterations`` iterations (deterministic for a seed), or ``refine_seconds`` of CPU.
    ``give_up_cut_off``: raise PlanningError as soon as the grid of corridors finds the next
    regions cut off from the prefix tree (for an attempt that another, with less clearance,
    follows). ``hold``: the clearance from obstacles kept where there is room (``keep_out``).
    """
    gen = rng if rng is not None else np.random.default_rng(options.seed)
    return _Planner(
        world, nba, start, clearance, options, gen, give_up_cut_off=give_up_cut_off, hold=hold
    ).run()
