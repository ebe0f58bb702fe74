"""The mission document: world, robot, task and planner options, validated as one model.

``MissionSpec`` composes the sections owned by each layer (``planner.spec.WorldSpec``,
``envs.spec.RobotSpec``, ``planner.options.PlannerSpec``) and adds the checks that need several
sections at once: every label of the task exists in the world, the robot lives in the world's
dimension, its start is free, and no goal region is buried in obstacles. ``parse_mission`` and
``load_mission`` turn any failure into a ``MissionError`` listing every problem with its dotted
path (``world.regions.g1.ball.radius: must be > 0``), the form the CLI prints and the API returns.
"""

from __future__ import annotations

import json
import re
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import yaml
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

from envs.spec import RobotSpec
from planner.errors import FormulaError, LtlnavError, WorldError
from planner.ltl import atoms, check_mission_formula, parse
from planner.options import PlannerSpec
from planner.spec import PROBLEMS_ERROR, RESERVED_LABEL, SHAPE_KINDS, WorldSpec, raise_problems
from planner.world import World

NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
GOAL_SAMPLES = 2000
"""Points sampled in a goal region to decide whether any of it is free."""


class MissionError(LtlnavError):
    """An invalid mission document; ``problems`` lists every ``(dotted path, message)``."""

    def __init__(self, problems: Sequence[tuple[str, str]]) -> None:
        self.problems: list[tuple[str, str]] = list(problems)
        super().__init__("\n".join(f"{path}: {message}" for path, message in self.problems))


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
    reason = err.reason
    if err.expected and "expected" not in reason:
        reason = f"{reason} (expected {err.expected})"
    return reason if err.column is None else f"column {err.column}: {reason}"


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

    _world: World | None = PrivateAttr(default=None)
    _world_key: tuple[str, tuple[float, ...]] | None = PrivateAttr(default=None)

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

    def labels(self) -> frozenset[str]:
        """The region labels the task mentions (without the reserved ``obstacle``)."""
        return atoms(parse(self.task)) - {RESERVED_LABEL}

    def _world_cache_key(self) -> tuple[str, tuple[float, ...]]:
        return self.world.model_dump_json(), tuple(float(v) for v in self.robot.position())

    def build_world(self) -> World:
        """The planner's world, generated obstacles kept clear of the robot's start; cached."""
        key = self._world_cache_key()
        if self._world is None or self._world_key != key:
            self._world = self.world.build(keep_clear=[self.robot.position()])
            self._world_key = key
        return self._world

    @model_validator(mode="after")
    def _consistent(self) -> MissionSpec:
        problems = self._label_problems()
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
                problems.append((err.field, err.reason))
            else:
                problems.extend(self._start_problems(world))
                problems.extend(self._goal_problems(world))
        raise_problems(problems)
        return self

    def _label_problems(self) -> list[tuple[str, str]]:
        defined = list(self.world.regions)
        known = ", ".join(defined) if defined else "no regions"
        unknown = sorted(
            self.labels() - set(defined), key=lambda s: (_label_column(self.task, s) or 0, s)
        )
        problems = []
        for label in unknown:
            column = _label_column(self.task, label)
            where = f" (column {column})" if column is not None else ""
            problems.append(("task", f"unknown label '{label}'{where}; the world defines {known}"))
        return problems

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


_SIMPLE_MESSAGES = {
    "missing": "required",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "int_type": "must be an integer",
    "int_parsing": "must be an integer",
    "int_from_float": "must be an integer",
    "string_type": "must be a string",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "list_type": "must be a list",
    "dict_type": "must be a mapping",
    "model_type": "must be a mapping",
    "model_attributes_type": "must be a mapping",
    "finite_number": "must be a finite number",
}
_COMPARISONS = {
    "greater_than": (">", "gt"),
    "greater_than_equal": (">=", "ge"),
    "less_than": ("<", "lt"),
    "less_than_equal": ("<=", "le"),
}


def _dotted(loc: Sequence[int | str]) -> list[str]:
    """Path parts of a pydantic location, without dict-key markers and union tags.

    A shape's tag equals the single key of the shape mapping that follows it, so a tag shows as
    the same name twice in a row; one of the two is dropped.
    """
    parts: list[str] = []
    i = 0
    while i < len(loc):
        item = loc[i]
        if item == "[key]":
            i += 1
            continue
        parts.append(str(item))
        twin = i + 1 < len(loc) and loc[i + 1] == item
        i += 2 if isinstance(item, str) and item in SHAPE_KINDS and twin else 1
    return parts


def _unwrap(tp: Any) -> Any:
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _field_type(tp: Any, part: str) -> Any:
    """The type found at ``part`` inside ``tp`` (model field, list item, dict value, union)."""
    tp = _unwrap(tp)
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        members = [_unwrap(m) for m in typing.get_args(tp) if m is not type(None)]
        for member in members:
            is_model = isinstance(member, type) and issubclass(member, BaseModel)
            if is_model and part in member.model_fields:
                return member.model_fields[part].annotation
        return _field_type(members[0], part) if len(members) == 1 else None
    if origin is list:
        return typing.get_args(tp)[0] if part.isdigit() else None
    if origin is dict:
        return typing.get_args(tp)[1]
    if isinstance(tp, type) and issubclass(tp, BaseModel) and part in tp.model_fields:
        return tp.model_fields[part].annotation
    return None


def _allowed_keys(root: type[BaseModel], parts: list[str]) -> list[str]:
    """The keys the model at ``parts`` accepts, or [] if the path does not lead to a model."""
    tp: Any = root
    for part in parts:
        tp = _field_type(tp, part)
        if tp is None:
            return []
    tp = _unwrap(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        models = [_unwrap(m) for m in typing.get_args(tp) if m is not type(None)]
        tp = models[0] if len(models) == 1 else None
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return list(tp.model_fields)
    return []


def _message(err: Any, parts: list[str], root: type[BaseModel]) -> str:
    """pydantic's message, made short: ``must be > 0`` rather than ``Input should be ...``."""
    kind, ctx = err["type"], err.get("ctx") or {}
    if kind in _SIMPLE_MESSAGES:
        return _SIMPLE_MESSAGES[kind]
    if kind in _COMPARISONS:
        symbol, key = _COMPARISONS[kind]
        limit = ctx.get(key)
        return (
            f"must be {symbol} {limit:g}"
            if isinstance(limit, float)
            else f"must be {symbol} {limit}"
        )
    if kind == "extra_forbidden":
        allowed = _allowed_keys(root, parts[:-1])
        return "unknown key" + (f"; allowed here: {', '.join(allowed)}" if allowed else "")
    if kind == "too_short":
        return f"needs at least {ctx.get('min_length')} items, got {ctx.get('actual_length')}"
    if kind == "too_long":
        return f"takes at most {ctx.get('max_length')} items, got {ctx.get('actual_length')}"
    message = str(err["msg"])
    for prefix in ("Value error, ", "Assertion failed, "):
        message = message.removeprefix(prefix)
    if message.startswith("Input should be "):
        message = "must be " + message.removeprefix("Input should be ")
    return message


def problems_from_validation_error(
    error: ValidationError, root: type[BaseModel]
) -> list[tuple[str, str]]:
    """Every problem of a pydantic error as ``(dotted path, short message)``, in order."""
    problems: list[tuple[str, str]] = []
    for err in error.errors():
        parts = _dotted(err["loc"])
        if err["type"] == PROBLEMS_ERROR:
            for sub, message in err["ctx"]["problems"]:
                problems.append((".".join([*parts, sub]) if sub else ".".join(parts), message))
            continue
        problems.append((".".join(parts) or "mission", _message(err, parts, root)))
    return problems


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that rejects a key repeated in one mapping (YAML keeps the last)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key '{key}'", key_node.start_mark
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_document(path: Path) -> Any:
    """Parse a YAML or JSON file; ``ValueError`` names the line of a syntax error."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        raise ValueError(f"cannot read the file: {reason}") from err
    if not text.strip():
        raise ValueError("the file is empty")
    suffix = path.suffix.lower()
    if suffix == ".json" or (suffix not in (".yaml", ".yml") and text.lstrip().startswith("{")):
        try:
            return json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(
                f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}"
            ) from err
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
        problem = getattr(err, "problem", None) or str(err)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise ValueError(f"invalid YAML{where}: {problem}") from err


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
        raise MissionError(problems_from_validation_error(err, MissionSpec)) from err


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
