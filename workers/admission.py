"""Admission of a mission document: validated, and within ``workers.limits.AdmissionLimits``.

``admit`` is what the CLI (``ltlnav validate``, ``ltlnav train``) and the API
(``POST /missions``) call, so a refusal reads the same everywhere. It runs in three steps:
``document_problems`` counts, on the raw document, what is costly to validate (polygon
vertices, obstacles, regions, formula length), so that a 50,000-vertex polygon is refused
before pydantic builds it; ``parse_mission`` validates; ``mission_problems`` checks the
budget, planner and hyperparameter fields of the validated spec.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from planner.errors import AutomatonTooLargeError
from planner.ltl.formula import (
    Eventually,
    Formula,
    Globally,
    Next,
    Release,
    Until,
    WeakUntil,
    parse,
)
from planner.ltl.formula import children as formula_children
from workers.documents import read_document
from workers.limits import (
    AdmissionLimits,
    Problem,
    automaton_problems,
    count_over,
    number,
    over,
    subtask_problems,
    translation_budget,
    translation_problems,
)
from workers.mission import MissionError, MissionSpec, parse_mission
from workers.training_spec import TrainingSpec

if TYPE_CHECKING:
    from planner.geometry.world import World
    from planner.ltl.automaton import Buchi
    from planner.plan import MissionPlan
    from planner.search.planner_spec import PlannerSpec

_TEMPORAL = (Until, Release, WeakUntil, Globally, Eventually, Next)


def admit(document: Any, limits: AdmissionLimits) -> MissionSpec:
    """The validated mission of ``document`` if it keeps ``limits``; else ``MissionError``
    with every problem (the counts are checked before validation builds any shape)."""
    problems = document_problems(document, limits)
    if problems:
        raise MissionError(problems)
    spec = parse_mission(document)
    problems = mission_problems(spec, limits)
    if problems:
        raise MissionError(problems)
    return spec


def load_admitted(path: str | Path, limits: AdmissionLimits) -> MissionSpec:
    """``workers.mission.load_mission`` with ``admit``'s limits."""
    try:
        data = read_document(Path(path))
    except ValueError as err:
        raise MissionError([(str(path), str(err))]) from err
    return admit(data, limits)


# ------------------------------------------------------------------------------ raw document


def document_problems(document: Any, limits: AdmissionLimits) -> list[Problem]:
    """Counts over the limits in a raw (unvalidated) document; parts of the wrong type are
    skipped (validation reports them). Linear in the document's size."""
    if not isinstance(document, dict):
        return []
    problems: list[Problem] = []
    task = document.get("task")
    if isinstance(task, str):
        message = count_over(len(task), "characters", "max_formula_chars", limits)
        if message:
            problems.append(("task", message))
    world = document.get("world")
    if isinstance(world, dict):
        problems.extend(_world_problems(world, limits))
    return problems


def _shapes(world: dict[str, Any]) -> Iterator[tuple[str, Any]]:
    obstacles, regions = world.get("obstacles"), world.get("regions")
    if isinstance(obstacles, list):
        for i, shape in enumerate(obstacles):
            yield f"world.obstacles.{i}", shape
    if isinstance(regions, dict):
        for label, shape in regions.items():
            yield f"world.regions.{label}", shape


def _world_problems(world: dict[str, Any], limits: AdmissionLimits) -> list[Problem]:
    problems: list[Problem] = []
    obstacles, regions = world.get("obstacles"), world.get("regions")
    listed = len(obstacles) if isinstance(obstacles, list) else 0
    generator = world.get("random_obstacles")
    count = generator.get("count") if isinstance(generator, dict) else None
    generated = count if isinstance(count, int) and not isinstance(count, bool) else 0
    if generated > 0:
        message = count_over(
            listed + max(generated, 0),
            f"obstacles ({listed} listed, {generated} generated)",
            "max_obstacles",
            limits,
        )
        where = "world.random_obstacles.count"
    else:
        message = count_over(listed, "obstacles", "max_obstacles", limits)
        where = "world.obstacles"
    if message:
        problems.append((where, message))
    if isinstance(regions, dict):
        message = count_over(len(regions), "regions", "max_regions", limits)
        if message:
            problems.append(("world.regions", message))
    total, alone = 0, False
    for path, shape in _shapes(world):
        vertices = shape.get("polygon") if isinstance(shape, dict) else None
        if not isinstance(vertices, list):
            continue
        total += len(vertices)
        message = count_over(len(vertices), "vertices", "max_world_vertices", limits)
        if message:
            problems.append((f"{path}.polygon", message))
            alone = True
    if not alone:
        message = count_over(total, "polygon vertices in all", "max_world_vertices", limits)
        if message:
            problems.append(("world", message))
    return problems


# ------------------------------------------------------------------------------ validated spec


def mission_problems(spec: MissionSpec, limits: AdmissionLimits) -> list[Problem]:
    """Fields of a validated mission over (or under) the limits, in document order."""
    problems: list[Problem] = []
    operators = _temporal_operators(parse(spec.task))
    message = count_over(operators, "temporal operators", "max_temporal_operators", limits)
    if message:
        problems.append(("task", message))
    planner = spec.planner
    checks: list[tuple[str, float | None, str]] = [
        ("planner.max_iterations", planner.max_iterations, "max_planner_iterations"),
        ("planner.time_limit", planner.time_limit, "max_planner_seconds"),
        ("planner.refine_iterations", planner.refine_iterations, "max_planner_iterations"),
        ("planner.refine_seconds", planner.refine_seconds, "max_planner_seconds"),
    ]
    problems.extend(_over_all(checks, limits))
    problems.extend(training_problems(spec.training, limits))
    return problems


def _temporal_operators(formula: Formula) -> int:
    stack, count = [formula], 0
    while stack:
        f = stack.pop()
        count += isinstance(f, _TEMPORAL)
        stack.extend(formula_children(f))
    return count


def _over_all(
    checks: list[tuple[str, float | None, str]], limits: AdmissionLimits
) -> list[Problem]:
    problems: list[Problem] = []
    for path, value, name in checks:
        message = None if value is None else over(value, name, limits)
        if message:
            problems.append((path, message))
    return problems


def training_problems(training: TrainingSpec, limits: AdmissionLimits) -> list[Problem]:
    """The ``training:`` section's fields over (or under) the limits."""
    t = training
    checks: list[tuple[str, float | None, str]] = [
        ("training.n_timesteps", t.n_timesteps, "max_timesteps"),
        ("training.eval_episodes", t.eval_episodes, "max_episodes"),
        ("training.final_eval_episodes", t.final_eval_episodes, "max_episodes"),
        ("training.mission_episodes", t.mission_episodes, "max_episodes"),
        ("training.cycles", t.cycles, "max_cycles"),
        ("training.handover_rounds", t.handover_rounds, "max_handover_rounds"),
        ("training.handover_steps", t.handover_steps, "max_timesteps"),
    ]
    env = t.env
    for key, name in (("max_steps", "max_episode_steps"), ("rays", "max_rays")):
        value = env.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool):
            checks.append((f"training.env.{key}", value, name))
    problems = _over_all(checks, limits)
    problems.extend(_frequency_problems(t, limits))
    problems.extend(_hyperparameter_problems(t, limits))
    return problems


def _frequency_problems(t: TrainingSpec, limits: AdmissionLimits) -> list[Problem]:
    problems: list[Problem] = []
    for key, value, name in (
        ("eval_freq", t.eval_freq, "max_evaluations"),
        ("checkpoint_freq", t.checkpoint_freq, "max_checkpoints"),
    ):
        most = getattr(limits, name)
        floor = math.ceil(t.n_timesteps / most)
        if value is not None and value < floor:
            what = "evaluations" if name == "max_evaluations" else "checkpoints"
            problems.append(
                (
                    f"training.{key}",
                    f"{value} is under the limit {floor} (training.n_timesteps / "
                    f"{limits.setting(name)}: at most {most} {what} per training run)",
                )
            )
    return problems


_SIZES = {
    "batch_size": "max_batch_size",
    "gradient_steps": "max_gradient_steps",
    "n_epochs": "max_epochs",
}
"""Hyperparameters with a limit of their own."""

_BUFFERS = ("buffer_size", "n_steps")
"""Hyperparameters that size a buffer: at most ``n_timesteps`` (a larger one never fills, and
stable-baselines3 allocates it whole), or ``BUFFER_FLOOR`` for a tiny budget."""

BUFFER_FLOOR = 10_000
"""A buffer this small is always admitted (a few megabytes), whatever the budget."""


def _hyperparameter_problems(t: TrainingSpec, limits: AdmissionLimits) -> list[Problem]:
    problems: list[Problem] = []
    where = "training.hyperparams"
    for key, value in t.hyperparams.items():
        if key not in _SIZES and key not in _BUFFERS:
            continue
        if not isinstance(value, int | float) or isinstance(value, bool):
            problems.append((f"{where}.{key}", "must be an integer"))
        elif key in _SIZES:
            message = over(value, _SIZES[key], limits)
            if message:
                problems.append((f"{where}.{key}", message))
        elif value > max(t.n_timesteps, BUFFER_FLOOR):
            limit = max(t.n_timesteps, BUFFER_FLOOR)
            problems.append(
                (
                    f"{where}.{key}",
                    f"{number(value)} is over the limit {limit} (training.n_timesteps: a "
                    "buffer larger than the budget never fills; the budget is limited by "
                    f"{limits.setting('max_timesteps')})",
                )
            )
    kwargs = t.hyperparams.get("policy_kwargs")
    if isinstance(kwargs, dict):
        problems.extend(_network_problems(kwargs, f"{where}.policy_kwargs", limits))
    return problems


def _network_problems(kwargs: dict[str, Any], where: str, limits: AdmissionLimits) -> list[Problem]:
    problems: list[Problem] = []
    arch = kwargs.get("net_arch")
    nets = arch.items() if isinstance(arch, dict) else [("", arch)]
    for name, layers in nets:
        if not isinstance(layers, list):
            continue
        path = f"{where}.net_arch" + (f".{name}" if name else "")
        message = count_over(len(layers), "layers", "max_net_depth", limits)
        if message:
            problems.append((path, message))
        widths = [n for n in layers if isinstance(n, int | float) and not isinstance(n, bool)]
        widest = max(widths, default=0)
        if widest > limits.max_net_width:
            setting = limits.setting("max_net_width")
            message = f"a layer of {number(widest)} units is over the limit "
            problems.append((path, message + f"{limits.max_net_width} ({setting})"))
    critics = kwargs.get("n_critics")
    if isinstance(critics, int | float) and not isinstance(critics, bool):
        message = over(critics, "max_critics", limits)
        if message:
            problems.append((f"{where}.n_critics", message))
    return problems


def servable_problems(mission: MissionSpec) -> list[tuple[str, str]]:
    """Why ltlnav cannot train and bundle ``mission`` as ``(field, reason)`` pairs (none: it
    can). The bundle concatenates one agent per sub-task, so a mode that trains one agent for
    the whole lasso is refused before anything is stored."""
    if mission.training.reward.mode == "g-rrt":
        return [
            (
                "training.reward.mode",
                "g-rrt trains one agent for the whole lasso; ltlnav trains and bundles one "
                "agent per sub-task: use rrt, rrt-paper, ned or tl",
            )
        ]
    return []


def admitted_automaton(mission: MissionSpec, world: World, limits: AdmissionLimits) -> Buchi:
    """The mission's automaton, translated within ``limits``: ``MissionError`` on ``task`` when
    the translation outgrows ``translation_budget`` or the automaton, pruned for the world, has
    more states than ``limits.max_automaton_states``."""
    from planner.plan import translate_task  # the planner: not for the API's admission

    try:
        nba, pruned = translate_task(
            mission.task, world, mission.robot.radius, translation_budget(limits)
        )
    except AutomatonTooLargeError as error:
        raise MissionError(translation_problems(limits)) from error
    too_large = automaton_problems(nba.num_states, pruned.num_states, limits)
    if too_large:
        raise MissionError(too_large)
    return nba


def admitted_plan(
    mission: MissionSpec, world: World, limits: AdmissionLimits, options: PlannerSpec
) -> MissionPlan:
    """The mission's plan in ``world`` under planner ``options``, within ``limits``: its
    automaton as ``admitted_automaton`` admits it, and ``MissionError`` when the plan has more
    sub-tasks than ``limits.max_subtasks`` (``PlanningError`` when the mission is infeasible)."""
    from planner.plan import plan_mission  # the planner: not for the API's admission

    nba = admitted_automaton(mission, world, limits)
    robot = mission.robot
    plan = plan_mission(world, mission.task, robot.position(), robot.radius, options, nba)
    too_many = subtask_problems(len(plan.subtasks), options.leg_length, limits)
    if too_many:
        raise MissionError(too_many)
    return plan
