"""Request and response models of the API (they document ``/openapi.json``), and the error
responses the routes share."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag

from service.models import JobStatus, MissionStatus
from workers.mission import MissionSpec


class Message(BaseModel):
    """An error with one sentence of explanation."""

    detail: str


class Problem(BaseModel):
    """One located problem of a request: ``loc`` is the path inside the request."""

    loc: list[str | int]
    msg: str
    type: str
    field: str | None = Field(None, description="Dotted path in the mission document.")
    column: int | None = Field(None, description="1-based column in the task formula.")


class Problems(BaseModel):
    """Every problem found in a request."""

    detail: list[Problem]


class ExampleRequest(BaseModel):
    """Submit one of the bundled example missions by name (``GET /examples``)."""

    model_config = ConfigDict(extra="forbid")

    example: str = Field(description="Name of the example (its file name without extension).")


SubmissionKind = Literal["mission", "example"]


def submission_kind(body: Any) -> SubmissionKind:
    """Which form of ``MissionCreate`` a body is: exactly one key ``example`` names an example,
    anything else is read as a mission document (and validated as one)."""
    return "example" if isinstance(body, dict) and set(body) == {"example"} else "mission"


MissionCreate = Annotated[
    Annotated[MissionSpec, Tag("mission")] | Annotated[ExampleRequest, Tag("example")],
    Discriminator(submission_kind),
]
"""The body of ``POST /missions``: a mission document (the schema of the mission files) or the
name of a bundled example. The tagged union documents it as ``oneOf`` the two."""


class MissionLinks(BaseModel):
    """Where to find a mission's resources."""

    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self")
    plan_png: str
    events: str
    cancel: str
    bundle: str
    curves: list[str] = Field(default_factory=list)


class Submitted(BaseModel):
    """A mission accepted for planning and training."""

    id: str
    status: MissionStatus
    links: MissionLinks


class JobView(BaseModel):
    """One sub-task's training job (``round`` 0), or its hand-over repair in round ``round``."""

    index: int
    round: int = Field(0, description="0: the sub-task's training; r > 0: its r-th repair.")
    status: JobStatus
    steps_done: int
    budget: int
    success_rate: float | None
    eta_seconds: float | None = Field(
        description="Estimated seconds left of the training (null before it can be estimated "
        "and once the training has ended)."
    )
    attempts: int
    reason: str | None = Field(
        description="Why the job is where it is: a retry's cause while queued, the evaluation "
        "it runs once its training has ended (e.g. 'picking the kept policy: 2 of 4'), a "
        "failure's error."
    )
    final: dict[str, Any] | None = Field(
        description="The final evaluation of the trained sub-policy (when done)."
    )
    seconds: float | None = Field(
        None, description="Wall seconds of the job's last training call (when done)."
    )
    time_by_part: dict[str, float] | None = Field(
        None,
        description="Those seconds by part (when done): periodic evaluations, confirmations, "
        "the start check, the final evaluation, checkpoints, the learner and the rest.",
    )


class MissionView(BaseModel):
    """A mission and where it is in its life cycle."""

    id: str
    name: str
    status: MissionStatus
    reason: str | None
    cancel_requested: bool
    created_at: datetime
    updated_at: datetime
    task: str
    robot: str | None = Field(description="The robot model.")
    plan: dict[str, Any] | None = Field(
        description="Plan summary once planned: automaton_states, pruned_states, "
        "prefix_length, suffix_length, cost, seconds, subtasks [{index, phase, goal, "
        "length, balls, r_ball}]: the r-balls its agent trains on."
    )
    jobs: list[JobView] = Field(description="One training job per sub-task, by index.")
    repairs: list[JobView] = Field(
        default_factory=list,
        description="Hand-over repair jobs, by round and sub-task: sub-tasks the mission's "
        "rollouts failed in, trained on from the poses they were handed the robot in.",
    )
    repair_rounds: list[dict[str, Any]] = Field(
        default_factory=list,
        description="Each judged repair round: round, subtasks, success_before, "
        "success_after, kept (only a round that raised the mission's success is kept).",
    )
    evaluation: dict[str, Any] | None = Field(
        description="The whole-mission evaluation (rollouts of the concatenated policy)."
    )
    links: MissionLinks


class MissionPageView(BaseModel):
    """One page of missions, newest first."""

    items: list[MissionView]
    total: int
    limit: int
    offset: int


class CurvePoint(BaseModel):
    """One periodic evaluation of a sub-task during training."""

    steps: int
    success_rate: float
    mean_return: float | None
    episodes: int


class Curve(BaseModel):
    """A sub-task's learning curve: success rate and return against steps."""

    index: int
    points: list[CurvePoint]


class ExampleView(BaseModel):
    """A bundled example mission."""

    name: str
    task: str
    robot: str


class Examples(BaseModel):
    """The bundled example missions."""

    examples: list[ExampleView]


ComponentState = Literal["ok", "down", "unknown"]


class Health(BaseModel):
    """Whether the API, the database and the broker are usable."""

    status: Literal["ok", "degraded"]
    api: ComponentState
    database: ComponentState
    broker: ComponentState
    open: bool = Field(description="True when no API keys are configured (no authentication).")
    problems: dict[str, str] = Field(default_factory=dict)


UNAUTHORIZED: dict[int | str, dict[str, Any]] = {
    401: {"model": Message, "description": "Missing or invalid API key."},
}
INVALID: dict[int | str, dict[str, Any]] = {
    422: {"model": Problems, "description": "A parameter or the body is invalid (located)."},
}
MISSION_ERRORS: dict[int | str, dict[str, Any]] = {
    **UNAUTHORIZED,
    **INVALID,
    404: {"model": Message, "description": "No such mission for this API key."},
}
"""The error responses of a route on one mission (``/missions/{mission_id}...``)."""
UNSAFE_ERRORS: dict[int | str, dict[str, Any]] = {
    403: {"model": Message, "description": "A browser sent it from another site (cross-site)."},
    415: {
        "model": Message,
        "description": "A body that is not 'Content-Type: application/json' (which a web page "
        "of another site cannot send unasked; see service/api/media_type.py).",
    },
}
"""The error responses of a state-changing route (POST, DELETE)."""
QUOTA_ERRORS: dict[int | str, dict[str, Any]] = {
    429: {
        "model": Message,
        "description": "A quota of the API key is used up (missions at once, submissions per "
        "minute); the message names the limit and its setting.",
        "headers": {
            "Retry-After": {
                "description": "Seconds to wait before submitting again.",
                "schema": {"type": "integer"},
            }
        },
    },
}
"""The error response of a submission over a quota."""
