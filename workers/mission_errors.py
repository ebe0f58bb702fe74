"""Located problems of a mission document: pydantic errors as dotted paths.

Every failure to validate a mission becomes ``(dotted path, short message)`` pairs, e.g.
``("world.regions.g1.ball.radius", "must be > 0")``: pydantic's locations lose their dict-key
markers and union tags and its wording is shortened. (A file that cannot be parsed at all is
``workers.documents``' ``ValueError``, which names the line.)
"""

from __future__ import annotations

import types
import typing
from collections.abc import Sequence
from typing import Annotated, Any

from pydantic import BaseModel, ValidationError

from planner.errors import LtlnavError
from planner.geometry.shape_spec import PROBLEMS_ERROR, SHAPE_KINDS


class MissionError(LtlnavError):
    """An invalid mission document; ``problems`` lists every ``(dotted path, message)``."""

    def __init__(self, problems: Sequence[tuple[str, str]]) -> None:
        self.problems: list[tuple[str, str]] = list(problems)
        super().__init__("\n".join(f"{path}: {message}" for path, message in self.problems))


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
