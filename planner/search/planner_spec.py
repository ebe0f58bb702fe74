"""Tuning options of the planner: the ``planner:`` section of a mission document."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

DEFAULT_REFINE_ITERATIONS = 1000
"""Default anytime budget in prefix iterations (see ``PlannerSpec.refine_iterations``)."""

REFINE_NODES_PER_ITERATION = 40
"""The anytime budget also ends once the prefix tree has this many new product nodes per
iteration of ``refine_iterations``: an iteration lifts its point onto every automaton state
near it, hundreds on an any-order task of many goals (2^k states), and costs accordingly."""


class PlannerSpec(BaseModel):
    """Options of TL-RRT* and of the decomposition into sub-tasks; every field is optional."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="Seed of the planner's random generator.")
    eta: float | None = Field(
        None,
        gt=0,
        description="RRT* steering step in workspace units; default: 1/20 of the "
        "workspace diagonal.",
    )
    r_ball: float | None = Field(
        None,
        gt=0,
        description="Radius of the guide's r-balls; default eta/2 (the paper's r <= eta/2). "
        "Training's shaped env narrows them to the plan's clearance unless "
        "training.env.r_ball_within_clearance is false.",
    )
    bias: float = Field(
        0.8,
        ge=0,
        le=1,
        description="Probability of sampling toward the automaton transition on the "
        "shortest path to acceptance (TL-RRT* biased sampling); the rest is uniform.",
    )
    max_iterations: int = Field(
        200_000,
        gt=0,
        description="Hard cap on TL-RRT* iterations for the prefix and for the suffix; "
        "exceeding it without a lasso is an infeasible mission.",
    )
    time_limit: float = Field(
        120.0, gt=0, description="CPU seconds to find a first lasso before giving up."
    )
    refine_iterations: int = Field(
        DEFAULT_REFINE_ITERATIONS,
        ge=0,
        description="Anytime budget spent improving the lasso after the first one is found, in "
        "iterations of the prefix tree (the suffix trees then restart from its roadmap): the plan "
        "depends only on the mission and the seed, not on the machine or its load (0: stop at "
        "the first lasso).",
    )
    refine_seconds: float | None = Field(
        None,
        ge=0,
        description="If set, the anytime budget is this many CPU seconds instead of "
        "refine_iterations (0: stop at the first lasso); the plan then depends on the speed and "
        "the load of the machine.",
    )
    prefix_weight: float = Field(
        0.2,
        ge=0,
        le=1,
        description="Lasso cost = prefix_weight * prefix length + (1 - prefix_weight) "
        "* suffix length, as in TL-RRT*.",
    )
    margin: float | None = Field(
        None,
        ge=0,
        description="Extra clearance (workspace units) the guide keeps from obstacles beyond the "
        "robot radius: the lasso is planned with radius + margin, and with the radius alone "
        "when that finds no plan (a passage too narrow). A unicycle swings out at every corner "
        "of the guide; a margin keeps following it off the boxes (bench/LEARNING.md). Default: "
        "the robot's own (0.3 for the point robot, the quadrotor and the racecar, whose "
        "feed-forward cuts the corners of a guide that grazes an obstacle; 0 for the unicycle).",
    )
    leg_length: float | None = Field(
        None,
        gt=0,
        description="Cut every sub-task whose guide is longer than this (workspace units) into "
        "legs of equal length, at most this long, each trained by its own agent and chained "
        "like sub-tasks (a leg ends in the last r-ball of its guide, the last one in the goal "
        "region). Default: none; bench/LEARNING.md compares legs with the feed-forwards.",
    )
    shortcut: bool = Field(
        True,
        description="Shorten the lasso by shortcutting waypoints while the automaton run and "
        "collision freedom are preserved.",
    )
