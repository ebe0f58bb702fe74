"""From a world and an LTL task to a verified lasso plan cut into sub-tasks.

:func:`plan_mission` runs the whole planner pipeline: parse and check the formula, translate it
to a Büchi automaton, prune the transitions this world can never produce (and those into
regions :mod:`planner.search.reachability` proves enclosed away from the start), plan a lasso with
TL-RRT* and decompose it. :func:`verify_plan` re-checks, independently of the planner's own
bookkeeping, every invariant the plan promises (issue section 6); an empty list means valid.
Times are CPU seconds (``time.process_time``): the machine is shared and wall time is noisy.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.collector import collection_paused
from planner.decompose import SubTask, decompose, split_into_legs
from planner.errors import PlanningError, unsatisfiable
from planner.geometry.world import World
from planner.ltl.automaton import Buchi
from planner.ltl.formula import check_mission_formula, parse
from planner.ltl.guard import Cube
from planner.ltl.prune import has_accepting_run, prune
from planner.ltl.semantics import holds_on_lasso
from planner.ltl.translate import translate
from planner.search.planner_spec import PlannerSpec
from planner.search.reachability import restrict_to_reachable
from planner.search.tl_rrt_star import Lasso, default_eta, plan_lasso

MARGIN_ITERATIONS = 10_000
"""Iterations per tree each attempt with a margin may spend before the plan tries less."""

MARGIN_SHARES = (1.0, 0.5)
"""Shares of ``planner.margin`` tried in turn before the robot radius alone: a door too narrow
for the whole margin often takes half of it. Measured with the zero action on the generated
tuning worlds (``bench/zero_grid.py``, seeds 0-19, margin 0.3 m), sub-tasks held with the whole
margin or the radius alone -> with half the margin in between: unicycle 47 -> 50 of 52, point
robot 48 -> 52 of 52 (the failures were rooms with 0.7-1 m doors)."""


@dataclass
class MissionPlan:
    """A planned mission: the automata, the lasso, its sub-tasks and how long it took.

    ``nba`` is the automaton of the formula, ``pruned`` the one TL-RRT* planned in (the lasso's
    and sub-tasks' automaton states refer to it). ``r_ball`` is the radius of the sub-tasks'
    guide balls and ``eta`` the steering step used. ``seconds`` covers the whole pipeline,
    ``translation_seconds`` parsing, translation and pruning (pruning alone when the automaton
    was given). ``clearance`` is the distance the lasso keeps from obstacles (the robot radius,
    plus the planner margin when it fit) and ``hold`` the distance it was pushed to wherever the
    free space leaves room (the radius plus the whole margin; at least ``clearance``).
    ``drawn`` fixes the drivable paths a car's envs drive for ``subtasks`` (a bundle records
    the ones its policies were trained on); None: the envs redraw them (``envs.drivable``).
    """

    formula: str
    start: np.ndarray
    nba: Buchi
    pruned: Buchi
    lasso: Lasso
    subtasks: list[SubTask]
    eta: float
    r_ball: float
    seconds: float
    translation_seconds: float
    clearance: float = 0.0
    hold: float = 0.0
    drawn: list[SubTask] | None = None

    def __post_init__(self) -> None:
        self.hold = max(self.hold, self.clearance)

    def to_json(self) -> dict[str, Any]:
        """The plan document of the ``ltlnav plan --json`` output (issue section 6)."""
        return {
            "formula": self.formula,
            "automaton": {
                "states": self.pruned.num_states,
                "transitions": self.pruned.num_transitions,
                "unpruned": {
                    "states": self.nba.num_states,
                    "transitions": self.nba.num_transitions,
                },
            },
            "prefix": self.lasso.prefix.tolist(),
            "suffix": self.lasso.suffix.tolist(),
            "cost": self.lasso.cost,
            "prefix_cost": self.lasso.prefix_cost,
            "suffix_cost": self.lasso.suffix_cost,
            "subtasks": [
                {
                    "index": s.index,
                    "phase": s.phase,
                    "goal": s.goal,
                    "path": s.path.tolist(),
                    "r_ball": self.r_ball,
                }
                for s in self.subtasks
            ],
            "clearance": self.clearance,
            "seconds": self.seconds,
        }


@collection_paused()
def translate_task(
    task: str, world: World, clearance: float, max_states: int | None = None
) -> tuple[Buchi, Buchi]:
    """The automaton of ``task`` and its pruning for ``world`` (FormulaError on bad input,
    PlanningError when no accepting run survives pruning, AutomatonTooLargeError when the
    translation outgrows ``max_states``)."""
    formula = parse(task)
    check_mission_formula(formula, task)
    nba = translate(formula, max_states)
    return nba, prune_for_world(nba, world, clearance)


def prune_for_world(nba: Buchi, world: World, clearance: float) -> Buchi:
    """``nba`` without the transitions whose labels no point of ``world`` at ``clearance`` from
    its obstacles realises (PlanningError when no accepting run survives)."""

    def realisable(cube: Cube) -> bool:
        return world.realisable(cube.pos, cube.neg, clearance)

    pruned = prune(nba, realisable)
    if not has_accepting_run(pruned):
        raise unsatisfiable(has_accepting_run(nba))
    return pruned


@collection_paused()
def plan_mission(
    world: World,
    task: str,
    start: np.ndarray,
    clearance: float,
    options: PlannerSpec | None = None,
    nba: Buchi | None = None,
) -> MissionPlan:
    """Plan ``task`` (LTL text) in ``world`` for a robot of radius ``clearance`` at ``start``,
    keeping ``options.margin`` more where a plan exists with it, else the largest share of it
    in ``MARGIN_SHARES`` that fits, else the radius alone (None: no margin; a mission's
    ``MissionSpec.planner_options`` gives its robot's); a plan with less than the whole margin
    keeps all of it wherever the free space leaves room (``planner.search.keep_out``).
    ``nba``: the automaton of ``task`` when the caller has translated it already
    (``translate_task``), so that it is translated once, not once per clearance tried.

    Raises FormulaError for a bad formula and PlanningError when no plan exists or none was
    found within the budget (the message says which).
    """
    opts = options if options is not None else PlannerSpec()
    # An iteration cap, not the CPU time limit, ends each attempt with a margin, so the choice
    # of the clearance is the same on every machine. An attempt also ends once the grid of
    # corridors finds the next regions cut off at its clearance (planner/search/corridor.py).
    capped = opts.model_copy(update={"max_iterations": min(opts.max_iterations, MARGIN_ITERATIONS)})
    margin = opts.margin or 0.0
    for share in MARGIN_SHARES if margin else ():
        try:
            held = clearance + share * margin
            return _plan(world, task, start, held, capped, nba, True, clearance + margin)
        except PlanningError:
            pass  # too narrow somewhere with this margin: try less of it
    return _plan(world, task, start, clearance, opts, nba, hold=clearance + margin)


def _plan(
    world: World,
    task: str,
    start: np.ndarray,
    clearance: float,
    opts: PlannerSpec,
    nba: Buchi | None,
    give_up_cut_off: bool = False,
    hold: float = 0.0,
) -> MissionPlan:
    t0 = time.process_time()
    if nba is None:
        nba, pruned = translate_task(task, world, clearance)
    else:
        pruned = prune_for_world(nba, world, clearance)
    pruned = restrict_to_reachable(pruned, world, np.asarray(start, dtype=float), clearance)
    t_translate = time.process_time() - t0
    rng = np.random.default_rng(opts.seed)
    lasso = plan_lasso(
        world, pruned, np.asarray(start, dtype=float), clearance, opts, rng, give_up_cut_off, hold
    )
    subtasks = decompose(lasso, pruned, world)
    if opts.leg_length is not None:
        subtasks = split_into_legs(subtasks, opts.leg_length)
    eta = opts.eta if opts.eta is not None else default_eta(world)
    return MissionPlan(
        formula=task,
        start=np.asarray(start, dtype=float).copy(),
        nba=nba,
        pruned=pruned,
        lasso=lasso,
        subtasks=subtasks,
        eta=eta,
        r_ball=opts.r_ball if opts.r_ball is not None else eta / 2.0,
        seconds=time.process_time() - t0,
        translation_seconds=t_translate,
        clearance=clearance,
        hold=hold,
    )


# ------------------------------------------------------------------------------ verification
def _dense_labels(
    world: World, points: np.ndarray, resolution: float, problems: list[str], what: str
) -> list[frozenset[str]]:
    """Labels met along the polyline, sampled every ``resolution`` at least and refined where
    the samples show fewer label changes than the world's exact count; stutters removed."""
    names = world.region_names
    word: list[frozenset[str]] = [world.labels(points[0])]
    for k in range(1, len(points)):
        a, b = points[k - 1], points[k]
        exact = world.segment_label_changes(a, b)
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / resolution)) + 1)
        for _ in range(3):
            t = np.linspace(0.0, 1.0, n)[:, None]
            pts = a + t * (b - a)
            member = world.label_matrix(pts)
            inside = world.in_collision(pts, 0.0)
            rows = np.concatenate([member, inside[:, None]], axis=1)
            if int(np.any(rows[1:] != rows[:-1], axis=1).sum()) >= exact:
                break
            n = min(n * 8, 200_000)
        else:
            problems.append(
                f"{what} segment {k - 1}: sampling finds fewer label changes than the world "
                f"counts ({exact}); it may graze a region boundary"
            )
        for row in rows[1:]:
            label = frozenset(nm for nm, m in zip(names, row[:-1], strict=True) if m)
            if row[-1]:
                label |= {World.OBSTACLE}
            if label != word[-1]:
                word.append(label)
    return word


def verify_plan(plan: MissionPlan, world: World, clearance: float) -> list[str]:
    """Every broken invariant of ``plan`` as a sentence; an empty list means valid.

    Checks: the prefix starts at the start position; ``suffix[0] == prefix[-1] ==
    suffix[-1]``; every waypoint and segment is collision free with ``clearance``; the
    sub-tasks chain along the lasso and each ends inside its goal region; and the labels met
    along ``prefix · suffix^ω`` (sampled densely, refined against the world's exact count of
    label changes) are accepted both by the automaton and by direct LTL evaluation.
    """
    problems: list[str] = []
    pre = np.asarray(plan.lasso.prefix, dtype=float)
    suf = np.asarray(plan.lasso.suffix, dtype=float)
    if len(pre) == 0 or len(suf) == 0:
        return ["the prefix and the suffix must each hold at least one point"]
    tol = 1e-9
    if not np.allclose(pre[0], plan.start, atol=tol):
        problems.append(f"prefix[0] {pre[0].tolist()} is not the start {plan.start.tolist()}")
    if not (np.allclose(suf[0], pre[-1], atol=tol) and np.allclose(suf[-1], pre[-1], atol=tol)):
        problems.append("suffix[0], prefix[-1] and suffix[-1] are not the same point")
    for name, path in (("prefix", pre), ("suffix", suf)):
        bad = np.flatnonzero(world.in_collision(path, clearance))
        if bad.size:
            problems.append(f"{name} waypoint(s) {bad.tolist()} in collision")
        if len(path) > 1:
            hit = np.flatnonzero(~world.segments_free(path[:-1], path[1:], clearance))
            if hit.size:
                problems.append(f"{name} segment(s) {hit.tolist()} not collision free")
    problems += _check_subtasks(plan, world, pre, suf)
    resolution = world.diagonal / 2000.0
    word = _dense_labels(world, pre, resolution, problems, "prefix")
    if len(suf) > 1:
        cycle = _dense_labels(world, suf, resolution, problems, "suffix")[1:]
    else:
        cycle = [word[-1]]
    if not cycle:
        cycle = [word[-1]]
    if not plan.nba.accepts_lasso(word, cycle):
        problems.append("the automaton rejects the label sequence of prefix . suffix^w")
    if not holds_on_lasso(parse(plan.formula), word, cycle):
        problems.append("the label sequence of prefix . suffix^w does not satisfy the formula")
    return problems


def _without_leg_knots(subs: list[SubTask], path: np.ndarray) -> np.ndarray | None:
    """The sub-tasks' paths joined, without the points where ``planner.leg_length`` cut a
    segment of ``path`` (None when such a point is off the segment it cut)."""
    points = list(np.asarray(subs[0].path, dtype=float))
    knots: list[int] = []
    for before, after in itertools.pairwise(subs):
        knot = points[-1]
        if before.goal == "" and not np.any(np.all(np.isclose(path, knot), axis=1)):
            knots.append(len(points) - 1)
        points.extend(np.asarray(after.path[1:], dtype=float))
    for k in knots:
        if not 0 < k < len(points) - 1 or not _on_segment(points[k], points[k - 1], points[k + 1]):
            return None
    cut = set(knots)
    return np.array([p for k, p in enumerate(points) if k not in cut])


def _on_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    ab = b - a
    t = float(np.clip(np.dot(point - a, ab) / max(float(np.dot(ab, ab)), 1e-300), 0.0, 1.0))
    return bool(np.linalg.norm(a + t * ab - point) <= 1e-9 * max(1.0, float(np.linalg.norm(ab))))


def _check_subtasks(plan: MissionPlan, world: World, pre: np.ndarray, suf: np.ndarray) -> list[str]:
    problems: list[str] = []
    for phase, path in (("prefix", pre), ("suffix", suf)):
        subs = [s for s in plan.subtasks if s.phase == phase]
        if len(path) > 1 and np.any(path[1:] != path[0]) and not subs:
            problems.append(f"the {phase} has no sub-task")
        if not subs:
            continue
        joined = _without_leg_knots(subs, path)
        if joined is None or joined.shape != path.shape or not np.allclose(joined, path):
            problems.append(f"the {phase} sub-task paths do not chain into the {phase}")
    for i, s in enumerate(plan.subtasks):
        if s.index != i:
            problems.append(f"sub-task {i} has index {s.index}")
        if not np.allclose(s.start, s.path[0]):
            problems.append(f"sub-task {i} does not start at its path's first point")
        if s.goal and s.goal not in world.labels(s.path[-1]):
            problems.append(f"sub-task {i} ends outside its goal region {s.goal}")
    return problems
