"""The body of ``POST /missions`` turned into a mission the service can run, or located problems.

The body is documented as ``MissionCreate`` (a mission document or ``{"example": name}``) but
arrives as decoded JSON (``MissionBody``); ``valid_submission`` validates it with
``workers.mission.parse_mission``, the validation of the CLI, so a problem reads the same
everywhere: its field path, the formula column for the task, unknown labels found even when
another section is invalid. A valid mission that the service can never run (``servable_problems``)
or one over the operator's admission limits (``workers.admission.admit``: counts checked on the
raw body before any shape is built, then budgets and sizes) is refused the same way, before
anything is stored."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Body, Depends
from pydantic import PlainValidator

from planner.errors import LtlnavError
from service.api.deps import ServicesDep, SubmissionSlot
from service.api.errors import body_problem, invalid
from service.api.examples import ExampleCatalogue
from service.api.json_body import decode_json
from service.api.schemas import MissionCreate, submission_kind
from workers.admission import admit, mission_problems, servable_problems
from workers.limits import AdmissionLimits
from workers.mission import MissionError, MissionSpec

log = logging.getLogger(__name__)

OPENAPI_EXAMPLES: dict[str, Any] = {
    "example": {
        "summary": "A bundled example, by name",
        "value": {"example": "car-phi2-fin"},
    },
    "mission": {
        "summary": "A mission document",
        "value": {
            "name": "patrol",
            "task": "[]<>a && []<>b",
            "robot": {"model": "point", "start": [0.5, 0.5], "radius": 0.05},
            "world": {
                "bounds": [[0, 4], [0, 4]],
                "obstacles": [{"box": {"min": [1.6, 1.6], "max": [2.4, 2.4]}}],
                "regions": {
                    "a": {"ball": {"center": [3.4, 0.6], "radius": 0.3}},
                    "b": {"box": {"min": [0.2, 3.2], "max": [0.8, 3.8]}},
                },
            },
        },
    },
}


def _decoded(body: Any) -> Any:
    # FastAPI hands over the raw bytes when the content type is not JSON (``curl -d`` sends a
    # form type); ``JsonBodyRoute`` has already checked that they are JSON.
    return decode_json(body) if isinstance(body, bytes) else body


MissionBody = Annotated[
    Any,
    PlainValidator(_decoded, json_schema_input_type=MissionCreate),
    Body(
        description='A mission document or {"example": name} (see GET /examples).',
        openapi_examples=OPENAPI_EXAMPLES,
    ),
]
"""The decoded JSON of the body, documented as ``MissionCreate``: checking it is CPU work (the
world is built and sampled), left to ``valid_submission`` in a worker thread."""


@dataclass(frozen=True)
class Submission:
    """A mission the service can run: the document to store and its validated spec."""

    document: dict[str, Any]
    spec: MissionSpec


def _validate(document: Any, limits: AdmissionLimits) -> MissionSpec:
    try:
        return admit(document, limits)
    except MissionError as error:
        raise invalid([body_problem(path, message) for path, message in error.problems]) from None
    except LtlnavError as error:
        raise invalid([body_problem("", str(error))]) from None
    except Exception as error:  # bad input must never give a 500: reject, and log the bug
        log.exception("validating a mission crashed")
        message = f"the mission could not be validated: {type(error).__name__}: {error}"
        raise invalid([body_problem("", message)]) from None


def _example(name: Any, catalogue: ExampleCatalogue) -> Submission:
    if not isinstance(name, str):
        raise invalid([body_problem("example", "must be a string", "type_error")])
    example = catalogue.get(name)
    if example is None:
        known = ", ".join(e.name for e in catalogue.all()) or "none"
        message = f"unknown example '{name[:80]}'; the examples are: {known}"
        raise invalid([body_problem("example", message, "unknown_example")])
    return Submission(document=example.document, spec=example.spec)


def _refuse_unservable(spec: MissionSpec, by_name: bool) -> None:
    """422 when the service can never train and bundle ``spec``, whatever it is given."""
    problems = servable_problems(spec)
    if by_name:  # the fields are in the example's file, not in the body
        problems = [("example", f"{field}: {reason}") for field, reason in problems]
    if problems:
        raise invalid([body_problem(path, reason, "unservable") for path, reason in problems])


def _refuse_over_limits(spec: MissionSpec, limits: AdmissionLimits) -> None:
    """422 when an example (checked when the catalogue loaded it, not against the limits)
    asks for more than the limits allow."""
    problems = [
        ("example", f"{field}: {reason}") for field, reason in mission_problems(spec, limits)
    ]
    if problems:
        raise invalid([body_problem(path, reason, "over_limit") for path, reason in problems])


def valid_submission(_slot: SubmissionSlot, body: MissionBody, deps: ServicesDep) -> Submission:
    """The mission of the body, validated fully (syntax, formula, world, robot) and one the
    service can train and bundle; else 422 with every problem located. A plain function, so
    FastAPI runs it in a worker thread, off the event loop."""
    by_name = submission_kind(body) == "example"
    limits = deps.settings.admission_limits()
    if by_name:
        submission = _example(body["example"], deps.examples)
        _refuse_over_limits(submission.spec, limits)
    else:
        submission = Submission(document=body, spec=_validate(body, limits))
    _refuse_unservable(submission.spec, by_name)
    return submission


ValidSubmission = Annotated[Submission, Depends(valid_submission)]
"""The validated mission of a ``POST /missions`` body."""
