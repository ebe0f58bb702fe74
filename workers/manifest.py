"""The format of a mission bundle: its version, its ``manifest.json`` schema and its error.

``workers.bundle`` writes a manifest of this schema, ``workers.bundle_reader`` reads and checks
one (pydantic, unknown keys rejected).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from planner.errors import LtlnavError

FORMAT = "ltlnav-bundle"
FORMAT_VERSION = 3
"""Version 3 records a car's drawn guides (``SubtaskEntry.drawn``); version 2 keeps the lasso
once, in ``plan``; version 1 also had it at the top level."""
READABLE_VERSIONS = frozenset({1, 2, 3})
"""Manifest versions this ltlnav reads."""
MANIFEST = "manifest.json"


class BundleError(LtlnavError):
    """A file that is not a valid ltlnav bundle (corrupted, foreign, or unsafe)."""


class DrawnGuide(BaseModel):
    """The drivable path a car's policy was trained to follow, redrawn from the plan's polyline
    (``envs.drivable``): driven backwards over ``path[: reverse + 1]``."""

    model_config = ConfigDict(extra="forbid")

    start: list[float]
    path: list[list[float]]
    reverse: int = 0


class SubtaskEntry(BaseModel):
    """One sub-task of the bundle: its guide and trained model."""

    model_config = ConfigDict(extra="forbid")

    index: int
    phase: Literal["prefix", "suffix"]
    goal: str
    start: list[float]
    path: list[list[float]]
    """The plan's polyline of the sub-task."""
    r_ball: float
    guide_centers: list[list[float]]
    """Centres of the r-balls of the guide the policy followed (the polyline's, or the redrawn
    path's under ``eval_env.drivable_guide``)."""
    drawn: DrawnGuide | None = None
    """A car's redrawn path (version 3 on): its rollouts drive it rather than today's redraw.
    None: the plan's polyline is driven, or the bundle predates the record."""
    model: str
    algorithm: Literal["sac", "td3", "ddpg", "ppo"]
    policy_kwargs: dict[str, Any]
    seed: int
    steps: int
    policy_steps: int | None = None
    """The kept policy's steps when not the last (``TrainResult.policy_steps``)."""
    selection: list[tuple[int, float, int]] = []
    """The pick's trials, ``(steps, success rate, episodes)`` (``TrainResult.selection``;
    empty without ``training.pick_candidates``)."""
    stopped: str
    repairs: int = 0
    """Hand-over repair rounds (``TrainResult.repairs``)."""
    curve: list[tuple[int, float]]
    evaluation: dict[str, Any] | None


class Manifest(BaseModel):
    """``manifest.json`` of a bundle (format ``ltlnav-bundle``, a version of
    ``READABLE_VERSIONS``)."""

    model_config = ConfigDict(extra="forbid")

    format: Literal["ltlnav-bundle"]
    format_version: int
    created: str
    mission: dict[str, Any]
    seeds: dict[str, Any]
    packages: dict[str, str]
    automaton_hoa: str
    pruned_automaton_hoa: str
    lasso: dict[str, Any] | None = None
    """Version 1 only: a copy of ``plan["lasso"]``."""
    plan: dict[str, Any]
    subtasks: list[SubtaskEntry]
    cycles: int
    mission_evaluation: dict[str, Any] | None
    eval_env: dict[str, Any] | None = None
    """The env options the policies were evaluated with and act under (``EnvOptions`` fields
    but ``rewards``; they fix what an action means: ``min_forward``, ``guide_feedforward``).
    None (bundles written before it was recorded): the mission's, under today's defaults."""
    files: list[str]
