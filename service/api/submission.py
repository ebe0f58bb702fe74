"""A submitted request body turned into a validated mission document, or located problems.

The body is JSON: a mission document (the schema of the mission files) or ``{"example":
name}``. Syntax errors give 400, every validation problem 422 with its field path (and the
column of the formula for the task)."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from typing import Any

from planner.errors import LtlnavError
from service.api.errors import ProblemsError, body_problem
from service.api.examples import ExampleCatalogue
from service.api.schemas import Problem
from workers.mission import MissionError, MissionSpec, parse_mission

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Submission:
    """A valid mission: the document to store and its validated spec."""

    document: dict[str, Any]
    spec: MissionSpec


def _syntax(message: str) -> ProblemsError:
    return ProblemsError(400, [Problem(loc=["body"], msg=message, type="json_invalid")])


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} is out of range")
    return value


def decode_json(raw: bytes) -> Any:
    """The JSON value of ``raw``; ``ProblemsError`` (400) naming the line and column of a
    syntax error. NaN, Infinity, out-of-range numbers and NUL characters are rejected (the
    databases cannot store them)."""
    if not raw.strip():
        raise _syntax('the request body is empty: send a mission document or {"example": name}')
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        raise _syntax(f"the body is not UTF-8 text: {error.reason} at byte {error.start}") from None
    try:
        value = json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float)
    except json.JSONDecodeError as error:
        message = f"invalid JSON at line {error.lineno}, column {error.colno}: {error.msg}"
        raise _syntax(message) from None
    except RecursionError:
        raise _syntax("invalid JSON: nested too deeply") from None
    except ValueError as error:
        raise _syntax(f"invalid JSON: {error}") from None
    if _has_nul(value):
        raise _syntax("invalid JSON: strings must not contain the NUL character (\\u0000)")
    return value


def _has_nul(value: Any) -> bool:
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            if "\x00" in item:
                return True
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return False


def _validate(document: Any, prefix: str = "") -> MissionSpec:
    try:
        return parse_mission(document)
    except MissionError as error:
        problems = [body_problem(prefix + path, message) for path, message in error.problems]
        raise ProblemsError(422, problems) from None
    except LtlnavError as error:
        raise ProblemsError(422, [body_problem(prefix, str(error))]) from None
    except Exception as error:  # bad input must never give a 500: reject, and log the bug
        log.exception("validating a mission crashed")
        message = f"the mission could not be validated: {type(error).__name__}: {error}"
        raise ProblemsError(422, [body_problem(prefix, message)]) from None


def _example(name: Any, catalogue: ExampleCatalogue) -> Submission:
    if not isinstance(name, str):
        raise ProblemsError(422, [body_problem("example", "must be a string", "type_error")])
    example = catalogue.get(name)
    if example is None:
        known = ", ".join(e.name for e in catalogue.all()) or "none"
        message = f"unknown example '{name[:80]}'; the examples are: {known}"
        raise ProblemsError(422, [body_problem("example", message, "unknown_example")])
    return Submission(document=example.document, spec=example.spec)


def submission(raw: bytes, catalogue: ExampleCatalogue) -> Submission:
    """The validated mission of a request body (see the module docstring)."""
    data = decode_json(raw)
    if isinstance(data, dict) and set(data) == {"example"}:
        return _example(data["example"], catalogue)
    spec = _validate(data)
    return Submission(document=data, spec=spec)
