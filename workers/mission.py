"""The mission document: world, robot, task, planner and training options, validated as one model.

``MissionSpec`` composes the sections owned by each layer
(``planner.geometry.world_spec.WorldSpec``, ``envs.spec.RobotSpec``,
``planner.search.planner_spec.PlannerSpec``) and adds the checks that need several sections at
once: every label of the task exists in the world, the robot lives in the world's dimension, its
start is free, and no goal region is buried in obstacles. ``parse_mission`` and ``load_mission``
turn any failure into a ``MissionError`` listing every problem with its dotted path
(``world.regions.g1.ball.radius: must be > 0``), the form the CLI prints and the API returns."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from envs.factory import subtask_guides
from envs.spec import RobotSpec
from planner.errors import FormulaError, WorldError
from planner.geometry.shape_spec import raise_problems
from planner.geometry.world import World
from planner.geometry.world_spec import RESERVED_LABEL, WorldSpec
from planner.ltl.formula import atoms, check_mission_formula, parse
from planner.search.planner_spec import PlannerSpec
from workers.documents import read_document
from workers.mission_errors import MissionError, problems_from_validation_error
from workers.training_spec import TrainingSpec

if TYPE_CHECKING:
    from planner.guidance import Guide
    from planner.plan import MissionPlan

__all__ = ["MissionError", "MissionSpec", "load_mission", "parse_mission"]

NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
GOAL_SAMPLES = 2000
"""Points sampled in a goal region to decide whether any of it is free."""


def _slug(name: str) -> str:
    if not NAME_PATTERN.fullmatch(name):
        raise PydanticCustomError(
            "name",
            "must be a slug of at most 64 letters, digits, '-', '_' or '.', starting with a "
            "letter or digit",
            {},
        )
    return name


def _label_column(text: str, label: str) -> int | None:
    """1-based column of the first occurrence of the proposition ``label`` in ``text``.

    Operators are upper-case letters or symbols, so only lower-case identifier characters can
    extend an identifier on either side.
    """
    match = re.search(rf"(?<![a-z0-9_]){re.escape(label)}(?![a-z0-9_])", text)
    return None if match is None else match.start() + 1


def _formula_problem(err: FormulaError) -> str:
    return err.reason if err.column is None else f"column {err.column}: {err.reason}"


def unknown_label_problems(task: str, defined: Sequence[str]) -> list[tuple[str, str]]:
    """One ``task`` problem per label of ``task`` that no region defines, in text order.

    ``task`` must parse; ``obstacle`` is always defined.
    """
    used = atoms(parse(task)) - {RESERVED_LABEL}
    known = ", ".join(defined) if defined else "no regions"
    unknown = sorted(used - set(defined), key=lambda s: (_label_column(task, s) or 0, s))
    problems = []
    for label in unknown:
        column = _label_column(task, label)
        where = f" (column {column})" if column is not None else ""
        problems.append(("task", f"unknown label '{label}'{where}; the world defines {known}"))
    return problems


class _WorldCache:
    """The built world and the (world JSON, start) it was built from.

    All caches compare equal so that two specs with the same fields are equal whether or not
    their worlds were built. A pickled cache is empty: a spec sent to another process builds its
    world there, once (a world holds closures that do not pickle).
    """

    def __init__(self) -> None:
        self.key: tuple[str, tuple[float, ...]] | None = None
        self.world: World | None = None

    def __reduce__(self) -> tuple[type[_WorldCache], tuple[()]]:
        return (_WorldCache, ())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _WorldCache)

    __hash__ = None  # type: ignore[assignment]


ROBOT_PLANNER_MARGIN: dict[str, float] = {
    "point": 0.3,
    "quadrotor": 0.3,
    "racecar": 0.3,
    "unicycle": 0.3,
}
"""``planner.margin`` of a mission that sets none, by robot model: the clearance beyond the
radius that the robot's feed-forward holds. Measured with the zero action on the generated
worlds of ``bench/generality.py`` (``bench/zero_grid.py``: tuning seeds 0-19, 20 starts a
sub-task), sub-tasks held with the radius alone -> with 0.3 m: quadrotor (3D cities) 38 -> 52
of 52, point robot (2D) 23 -> 48 of 52, racecar 9 -> 38 of 52, unicycle 26 -> 44 of 52 (with
a feed-forward lookahead of 0.3 s; 47 at the adopted 0.2 s). The rest were mostly worlds of
rooms whose narrowest door does not fit the margin; the plan now tries half of it there before
the radius alone (``planner.plan.MARGIN_SHARES``)."""


class MissionSpec(BaseModel):
    """A whole mission: where (world), who (robot), what (task) and how to plan it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: Annotated[str, AfterValidator(_slug)] = Field(
        "mission", description="Short identifier used for files and listings (a slug)."
    )
    world: WorldSpec = Field(description="Workspace bounds, obstacles and labelled regions.")
    robot: RobotSpec = Field(description="Robot model, start state, radius and parameters.")
    task: str = Field(
        description="LTL formula over the region labels (and 'obstacle'), in spin syntax "
        "([] <> ! && || -> <-> U R V) or letter syntax (G F & | U R W). Obstacles are always "
        "avoided; X (next) is not allowed."
    )
    planner: PlannerSpec = Field(
        default_factory=PlannerSpec, description="Optional planner tuning (seed, eta, ...)."
    )
    training: TrainingSpec = Field(
        default_factory=lambda: TrainingSpec(),
        description="Optional training options (algorithm, budget, reward, hyperparameters).",
    )

    _cache: _WorldCache = PrivateAttr(default_factory=lambda: _WorldCache())

    @field_validator("task")
    @classmethod
    def _formula(cls, task: str) -> str:
        try:
            check_mission_formula(parse(task), task)
        except FormulaError as err:
            raise PydanticCustomError(
                "formula", "{reason}", {"reason": _formula_problem(err)}
            ) from err
        return task

    def planner_options(self) -> PlannerSpec:
        """``planner`` with the robot's own margin where the mission sets none
        (``ROBOT_PLANNER_MARGIN``)."""
        if self.planner.margin is not None:
            return self.planner
        margin = ROBOT_PLANNER_MARGIN.get(self.robot.model, 0.0)
        return self.planner.model_copy(update={"margin": margin})

    def labels(self) -> frozenset[str]:
        """The region labels the task mentions (without the reserved ``obstacle``)."""
        return atoms(parse(self.task)) - {RESERVED_LABEL}

    def _world_cache_key(self) -> tuple[str, tuple[float, ...]]:
        return self.world.model_dump_json(), tuple(float(v) for v in self.robot.position())

    def build_world(self) -> World:
        """The planner's world, generated obstacles kept clear of the robot's start; cached."""
        key = self._world_cache_key()
        cache = self._cache
        if cache.world is None or cache.key != key:
            cache.world = self.world.build(keep_clear=[self.robot.position()])
            cache.key = key
        return cache.world

    def trained_guides(self, plan: MissionPlan) -> list[Guide]:
        """The guide each sub-task of ``plan`` is trained and evaluated on (r-balls narrowed to
        the plan's clearance, a car's path redrawn), as pictures and summaries show it."""
        options = self.training.eval_env_options(self.robot.model)
        return subtask_guides(self, plan, options, self.build_world())

    @model_validator(mode="after")
    def _consistent(self) -> MissionSpec:
        problems = unknown_label_problems(self.task, list(self.world.regions))
        robot, d = self.robot, self.world.dim
        if robot.workspace_dim != d:
            if robot.model == "point":
                problems.append(
                    (
                        "robot.start",
                        f"a point robot starting at {len(robot.start)} numbers is "
                        f"{robot.workspace_dim}D but the world is {d}D",
                    )
                )
            else:
                problems.append(
                    (
                        "robot.model",
                        f"a {robot.model} moves in {robot.workspace_dim}D but the "
                        f"world is {d}D (world.bounds has {d} intervals)",
                    )
                )
        else:
            try:
                world = self.build_world()
            except WorldError as err:
                field = err.field if err.field.startswith("world.") else f"world.{err.field}"
                problems.append((field, err.reason))
            else:
                problems.extend(self._start_problems(world))
                problems.extend(self._goal_problems(world))
        raise_problems(problems)
        return self

    def _start_problems(self, world: World) -> list[tuple[str, str]]:
        pos = self.robot.position()
        radius = self.robot.radius
        bounds = self.world.bounds_array()
        shown = "[" + ", ".join(f"{v:g}" for v in pos) + "]"
        if np.any(pos < bounds[:, 0]) or np.any(pos > bounds[:, 1]):
            return [
                (
                    "robot.start",
                    f"position {shown} lies outside the world bounds {self.world.bounds}",
                )
            ]
        if not world.in_collision(pos[None, :], clearance=radius)[0]:
            return []
        for i, spec in enumerate(self.world.obstacles):
            if spec.to_shape().contains(pos[None, :], margin=radius)[0]:
                return [
                    (
                        "robot.start",
                        f"position {shown} is in collision with "
                        f"world.obstacles.{i} (obstacles inflated by robot.radius {radius:g})",
                    )
                ]
        if np.min(np.abs(bounds - pos[:, None])) < radius:
            return [
                (
                    "robot.start",
                    f"position {shown} is closer than robot.radius {radius:g} "
                    "to the world boundary",
                )
            ]
        return [
            (
                "robot.start",
                f"position {shown} is in collision with a generated obstacle "
                f"(world.random_obstacles; raise its clearance above robot.radius {radius:g})",
            )
        ]

    def _goal_problems(self, world: World) -> list[tuple[str, str]]:
        problems = []
        used = self.labels()
        for label in self.world.regions:
            if label not in used:
                continue
            shape = self.world.regions[label].to_shape()
            points = shape.sample(np.random.default_rng(0), GOAL_SAMPLES)
            if world.in_collision(points, clearance=self.robot.radius).all():
                problems.append(
                    (
                        f"world.regions.{label}",
                        f"goal region lies entirely inside obstacles: none "
                        f"of {GOAL_SAMPLES} sampled points is free for a robot of radius "
                        f"{self.robot.radius:g}",
                    )
                )
        return problems


def parse_mission(data: Any) -> MissionSpec:
    """Validate a mission document (a mapping, e.g. parsed YAML/JSON); raise ``MissionError``."""
    if not isinstance(data, dict):
        raise MissionError(
            [
                (
                    "mission",
                    "a mission must be a mapping with keys name, world, robot, task, "
                    f"planner; got {type(data).__name__}",
                )
            ]
        )
    try:
        return MissionSpec.model_validate(data)
    except ValidationError as err:
        problems = problems_from_validation_error(err, MissionSpec)
        raise MissionError(problems + _partial_label_problems(data, problems)) from err


def _partial_label_problems(
    data: dict[str, Any], problems: list[tuple[str, str]]
) -> list[tuple[str, str]]:
    """Unknown task labels, found even when another section is invalid.

    The model's own check only runs on a fully valid document; labels need only the task and the
    region names, so they are checked here too when both are usable.
    """
    task, world = data.get("task"), data.get("world")
    regions = world.get("regions", {}) if isinstance(world, dict) else None
    if any(path == "task" for path, _ in problems):
        return []
    if not isinstance(task, str) or not isinstance(regions, dict):
        return []
    return unknown_label_problems(task, [str(k) for k in regions])


def load_mission(path: str | Path) -> MissionSpec:
    """Read a mission from a YAML or JSON file and validate it; raise ``MissionError``.

    The format follows the extension (``.json``, ``.yaml``/``.yml``), else the content. An
    unreadable file or a syntax error is a ``MissionError`` on the file's path naming the line.
    """
    try:
        data = read_document(Path(path))
    except ValueError as err:
        raise MissionError([(str(path), str(err))]) from err
    return parse_mission(data)
