"""``make_env``: the navigation env of one sub-task of a mission, and its Gymnasium id.

``make_env(mission, subtask, reward="rrt", **options)`` reads only the mission's ``world`` (a
``WorldSpec``-like object with ``build(keep_clear=...)``) and ``robot`` (``RobotSpec``): the
envs layer never imports ``workers``, so any object of the ``MissionLike`` shape will do. It is
also registered as ``ltlnav/Nav-v0``: ``gymnasium.make("ltlnav/Nav-v0", mission=m,
subtask=s, reward="rrt", ...)`` takes the same arguments. ``envs.options.EnvOptions`` documents
every option; ``build_course`` turns sub-tasks into the env's checked guides (``Leg``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym
import numpy as np

from envs.drivable import clearances, redraw_course
from envs.errors import EnvConfigError
from envs.handover import checked_starts, opening_pose, real_starts
from envs.leg import Leg
from envs.nav_env import NavEnv
from envs.options import EnvOptions, options_with
from envs.rewards import reward_mode
from envs.robots import (
    Robot,
    RobotConfigError,
    make_robot,
    nominal_speed,
    robot_class,
    robot_params,
)
from envs.spec import RobotSpec
from envs.track import Track
from planner.geometry.drivable import thin
from planner.geometry.pose import Pose, heading_along
from planner.geometry.region_test import RegionTest
from planner.geometry.world import World
from planner.guidance import Guide, ProgressTracker

if TYPE_CHECKING:
    from planner.decompose import SubTask
    from planner.plan import MissionPlan

ENV_ID = "ltlnav/Nav-v0"
"""The Gymnasium id of the navigation env."""


class WorldSource(Protocol):
    """What ``make_env`` needs of a mission's world section: a way to build the ``World``."""

    def build(self, keep_clear: Sequence[np.ndarray] = ()) -> World: ...


class MissionLike(Protocol):
    """What ``make_env`` needs of a mission (``workers.mission.MissionSpec`` fits)."""

    @property
    def world(self) -> WorldSource: ...

    @property
    def robot(self) -> RobotSpec: ...


def make_env(
    mission: MissionLike,
    subtask: SubTask | int | None = None,
    reward: str = "rrt",
    *,
    world: World | None = None,
    plan: MissionPlan | None = None,
    robot: Robot | None = None,
    render_mode: str | None = None,
    options: EnvOptions | None = None,
    starts: Sequence[Pose] | None = None,
    **overrides: Any,
) -> NavEnv:
    """The navigation env of ``subtask`` of ``mission`` under reward mode ``reward``.

    ``subtask`` is a ``SubTask`` or an index into ``plan.subtasks``; ``g-rrt`` drives the
    whole lasso and takes None. ``world`` is the mission's prebuilt world (otherwise built from
    ``mission.world`` with the robot's start kept clear, as ``MissionSpec.build_world`` does);
    ``plan`` is required by ``tl`` and ``g-rrt`` (automaton, every sub-task) and supplies the
    r-ball radius. ``robot`` shares an already built robot (the env will not close it), e.g.
    to hand over between the sub-task envs of a mission rollout. ``starts`` replaces the real
    starts (``envs.handover``), e.g. by the poses measured rollouts handed over in.
    ``options`` and keyword ``overrides`` (any ``EnvOptions`` field; ``rewards`` may be a
    mapping) tune the env.

    Raises ``EnvConfigError`` (a ``ValueError``) for an unknown reward mode or option, a missing
    plan, a start of the wrong dimension or in collision, and ``RobotConfigError`` (also a
    ``ValueError``) for an unknown robot model or a world the robot cannot move in.
    """
    opts = options_with(options, overrides)
    mode = reward_mode(reward, opts.rewards)
    spec = mission.robot
    model = robot_class(spec.model)
    if world is None:
        world = mission.world.build(keep_clear=[spec.position()])
    if world.dim not in model.workspace_dims:
        allowed = " or ".join(f"{d}D" for d in model.workspace_dims)
        raise RobotConfigError(
            "model",
            f"a {spec.model} robot moves in a {allowed} workspace, but the world is {world.dim}D",
        )
    start = np.asarray(spec.position(), dtype=float)
    if start.shape != (world.dim,):
        raise EnvConfigError(
            "robot.start",
            f"the {spec.model} robot starts at a {start.shape[0]}D position but the world is "
            f"{world.dim}D",
        )
    if mode.automaton and plan is None:
        raise EnvConfigError(
            "plan",
            f"reward mode {reward!r} needs the mission plan (its automaton and sub-tasks): "
            "pass plan=",
        )
    if mode.whole_lasso:
        if subtask is not None:
            raise EnvConfigError(
                "subtask", f"reward mode {reward!r} drives the whole lasso: pass subtask=None"
            )
        assert plan is not None
        subtasks = list(plan.subtasks)
    else:
        subtasks = [_subtask(subtask, plan)]
    if plan is not None and plan.start.shape != (world.dim,):
        raise EnvConfigError("plan", f"the plan is {plan.start.shape[0]}D, the world {world.dim}D")
    legs, real = course(world, spec, subtasks, plan, opts, whole_lasso=mode.whole_lasso)
    if starts is not None:
        real = checked_starts(starts, world)
    own = robot is None
    bot = robot if robot is not None else make_robot(spec.model, world, spec.radius, spec.params)
    try:
        return NavEnv(
            world,
            bot,
            legs,
            mode,
            opts,
            max_steps=opts.max_steps or default_max_steps(legs, bot, opts.time_factor),
            stall_steps=stall_window(legs, bot, opts),
            starts=real,
            nba=plan.pruned if plan is not None else None,
            render_mode=render_mode,
            owns_robot=own,
        )
    except BaseException:
        if own:
            bot.close()
        raise


def course(
    world: World,
    spec: RobotSpec,
    subtasks: list[SubTask],
    plan: MissionPlan | None,
    opts: EnvOptions,
    *,
    whole_lasso: bool,
) -> tuple[list[Leg], list[Pose]]:
    """The legs an env drives through ``subtasks`` (one, or every sub-task of ``plan`` for the
    whole lasso) and its real starts (``envs.handover``), the guides redrawn for a car under
    ``opts.drivable_guide``."""
    start = np.asarray(spec.position(), dtype=float)
    r_ball = opts.r_ball or (plan.r_ball if plan is not None else world.diagonal / 40.0)
    within = opts.r_ball is None and opts.r_ball_within_clearance
    if within and plan is not None and plan.clearance > 0:
        r_ball = min(r_ball, plan.clearance)
    given = _given_heading(spec, world.dim)
    pool, chosen, opening, dense = _pool(world, spec, subtasks, plan, opts)
    if dense:
        subtasks = pool if whole_lasso else [pool[chosen or 0]]
    legs = build_course(
        world, spec.radius, subtasks, r_ball, dense=dense, window=opts.progress_window
    )
    handover_of = chosen if opts.handover and not whole_lasso else None
    guide_heading = legs[0].headings[0]
    real = real_starts(world, pool, subtasks[0], handover_of, opening, start, given, guide_heading)
    return legs, real


def _given_heading(spec: RobotSpec, dim: int) -> float | None:
    """The heading the mission gives the robot at its start (None: along the guide)."""
    return float(spec.start[dim]) if len(spec.start) > dim else None


def _pool(
    world: World,
    spec: RobotSpec,
    subtasks: list[SubTask],
    plan: MissionPlan | None,
    opts: EnvOptions,
) -> tuple[list[SubTask], int | None, Pose, bool]:
    """The course ``subtasks[0]`` belongs to (every sub-task of ``plan``, else ``subtasks``),
    its position there, the course's opening pose, and whether the course was redrawn for a
    car (``opts.drivable_guide``; the plan's record of drawn paths when it has one)."""
    listed = plan.subtasks if plan is not None else []
    chosen = next((i for i, s in enumerate(listed) if s is subtasks[0]), None)
    pool = list(plan.subtasks) if plan is not None and chosen is not None else subtasks
    opening = opening_pose(
        pool, np.asarray(spec.position(), dtype=float), _given_heading(spec, world.dim)
    )
    rho = _turning_radius(opts, spec)
    if rho <= 0:
        return pool, chosen, opening, False
    if plan is not None and chosen is not None and plan.drawn is not None:
        return list(plan.drawn), chosen, opening, True
    steps = clearances(spec.radius, plan.hold if plan is not None else spec.radius)
    return redraw_course(world, pool, opening, rho, steps), chosen, opening, True


def drawn_subtasks(
    mission: MissionLike, plan: MissionPlan, options: EnvOptions, world: World | None = None
) -> list[SubTask] | None:
    """``plan``'s sub-tasks as a car's envs drive them under ``options`` (the redrawn paths of
    ``drivable_guide``); None where the envs drive the plan's polylines."""
    if world is None:
        world = mission.world.build(keep_clear=[mission.robot.position()])
    pool, _, _, dense = _pool(world, mission.robot, list(plan.subtasks), plan, options)
    return pool if dense else None


def subtask_guides(
    mission: MissionLike, plan: MissionPlan, options: EnvOptions, world: World | None = None
) -> list[Guide]:
    """The guide each sub-task's env follows under ``options``: what its policy was trained on
    (the plan's polyline, or the redrawn path of ``drivable_guide``)."""
    spec = mission.robot
    if world is None:
        world = mission.world.build(keep_clear=[spec.position()])
    return [
        course(world, spec, [sub], plan, options, whole_lasso=False)[0][0].guide
        for sub in plan.subtasks
    ]


def build_course(
    world: World,
    radius: float,
    subtasks: Sequence[SubTask],
    r_ball: float,
    *,
    dense: bool = False,
    window: int | None = None,
) -> list[Leg]:
    """One ``Leg`` (guide of ``r_ball`` balls, tracker, goal test) per sub-task, checked
    against ``world`` for a robot of ``radius``: points of the world's dimension, known goal
    regions, and a first start inside the bounds and collision free. ``dense`` paths (redrawn
    by ``envs.drivable``) are thinned to balls ``2 r_ball`` apart along them; ``window`` is the
    trackers' progress window."""
    d = world.dim
    guides: list[Guide] = []
    tracks: list[Track] = []
    for k, sub in enumerate(subtasks):
        start, path = np.asarray(sub.start, dtype=float), np.asarray(sub.path, dtype=float)
        if start.shape != (d,):
            raise EnvConfigError(
                "subtask.start",
                f"sub-task {k} starts at a point of shape {start.shape}; the world is {d}D",
            )
        if path.ndim != 2 or path.shape[1] != d or len(path) == 0:
            raise EnvConfigError("subtask.path", f"sub-task {k}: the path must be (n, {d})")
        if sub.goal and sub.goal not in world.regions:
            known = ", ".join(world.region_names) or "none"
            raise EnvConfigError(
                "subtask.goal", f"sub-task {k}: no region {sub.goal!r} (known: {known})"
            )
        if dense:
            balls = thin(path, 2.0 * r_ball)
            guide = Guide.from_path(balls, r_ball)
            assert guide.num_balls == len(balls)  # thinned chords are never longer than 2 r
            slack = world.obstacle_distance(path) - radius
            tracks.append(Track.dense(path, guide.num_balls, sub.reverse, slack))
        else:
            guide = Guide.from_path(path, r_ball)
            tracks.append(Track.of_guide(guide))
        guides.append(guide)
    if not subtasks:
        raise EnvConfigError("subtask", "no sub-task to drive")
    start = np.asarray(subtasks[0].start, dtype=float)
    if np.any(start < world.bounds[:, 0]) or np.any(start > world.bounds[:, 1]):
        raise EnvConfigError("subtask.start", f"{start.tolist()} is outside the world bounds")
    if world.in_collision(start[None, :], radius)[0]:
        raise EnvConfigError(
            "subtask.start", f"{start.tolist()} is in collision for a robot of radius {radius:g}"
        )
    legs: list[Leg] = []
    offset = 0
    lengths = [g.length for g in guides]
    for k, (sub, guide, track) in enumerate(zip(subtasks, guides, tracks, strict=True)):
        goal = RegionTest(world.regions[sub.goal]) if sub.goal else None
        headings = [heading_along(guide.centers[i:]) for i in range(guide.num_balls)]
        cusp = track.cusp_togo
        if cusp is not None:  # balls of a reversing lead: the car faces back along it
            lead = np.asarray(track.ball_togo) > cusp
            headings = [h + math.pi * bool(on) for h, on in zip(headings, lead, strict=True)]
        tracker = ProgressTracker(guide, window=window)
        rest = sum(lengths[k + 1 :])
        legs.append(Leg(sub, guide, tracker, offset, rest, goal, headings, track))
        offset += guide.num_balls
    return legs


def _turning_radius(options: EnvOptions, spec: RobotSpec) -> float:
    """Turning radius of the drivable guides (0: the plan's polylines)."""
    if options.drivable_guide is None:
        return 0.0
    tightest = robot_params(spec.model, spec.params).min_turning_radius()
    if tightest <= 0:
        raise EnvConfigError(
            "options.drivable_guide",
            f"only for robots with a minimum turning radius (racecar), not a {spec.model}",
        )
    return options.drivable_guide * tightest


def default_max_steps(legs: Sequence[Leg], robot: Robot, time_factor: float) -> int:
    """``max(50, ceil(time_factor * L / (v dt)))``: see ``EnvOptions.max_steps``."""
    length = sum(leg.guide.length for leg in legs)
    return max(50, math.ceil(time_factor * length / (nominal_speed(robot) * robot.dt)))


STALL_MIN_SECONDS = 3.0
"""The shortest stall window ``stall_spacings`` gives: the 30 steps of 0.1 s that took the car
example's U-turn sub-task from 0 to 98 % (``bench/LEARNING.md``), the time a (forward, turn)
robot needs to turn toward a ball behind it."""


def stall_window(legs: Sequence[Leg], robot: Robot, options: EnvOptions) -> int:
    """Steps without a new r-ball that end an episode (0: never): ``options.stall_steps``, or
    with ``stall_spacings`` ``s``, ``max(ceil(STALL_MIN_SECONDS / dt), ceil(s 2 r / (v dt)))``
    with ``r`` the widest ball of ``legs``, ``v`` the robot's top speed and ``dt`` its agent
    step: at a ``1 / s`` share of its top speed the robot still reaches a ball every window."""
    if options.stall_spacings is None:
        return options.stall_steps
    spacing = 2.0 * max(leg.guide.r for leg in legs)
    travel = options.stall_spacings * spacing / nominal_speed(robot)
    return math.ceil(max(STALL_MIN_SECONDS, travel) / robot.dt - 1e-9)


def _subtask(subtask: SubTask | int | None, plan: MissionPlan | None) -> SubTask:
    if subtask is None:
        raise EnvConfigError("subtask", "this reward mode trains one sub-task: pass one")
    if isinstance(subtask, bool):
        raise EnvConfigError("subtask", f"expected a SubTask or an index, got {subtask!r}")
    if isinstance(subtask, int | np.integer):
        if plan is None:
            raise EnvConfigError("subtask", "a sub-task index needs plan=")
        if not 0 <= subtask < len(plan.subtasks):
            raise EnvConfigError(
                "subtask", f"index {subtask} out of range: the plan has {len(plan.subtasks)}"
            )
        return plan.subtasks[int(subtask)]
    # Checked by shape, not class: any object with a SubTask's fields will do.
    if all(hasattr(subtask, a) for a in ("start", "path", "goal", "nba_state", "next_nba_state")):
        return subtask
    raise EnvConfigError("subtask", f"expected a SubTask or an index, got {subtask!r}")


def register_env() -> None:
    """Register ``ltlnav/Nav-v0`` with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="envs.factory:make_env")


register_env()
