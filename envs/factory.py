"""``make_env``: the navigation env of one sub-task of a mission, its options and Gymnasium id.

``make_env(mission, subtask, reward="rrt", **options)`` reads only the mission's ``world`` (a
``WorldSpec``-like object with ``build(keep_clear=...)``) and ``robot`` (``RobotSpec``): the
envs layer never imports ``workers``, so any object of the ``MissionLike`` shape will do. It is
also registered as ``ltlnav/Nav-v0``: ``gymnasium.make("ltlnav/Nav-v0", mission=m,
subtask=s, reward="rrt", ...)`` takes the same arguments. ``EnvOptions`` documents every
option; ``build_course`` turns sub-tasks into the env's checked guides (``Leg``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym
import numpy as np

from envs.handover import Pose, checked_starts, handover_poses
from envs.nav_env import Leg, NavEnv
from envs.observation import ObservationMode
from envs.rewards import EnvConfigError, RegionTest, RewardConfig, reward_config, reward_mode
from envs.robots import Robot, RobotConfigError, make_robot, robot_class
from envs.robots.racecar import WHEEL_RADIUS, RacecarParams
from envs.spec import RobotSpec
from planner.guidance import Guide, ProgressTracker
from planner.world import World

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


@dataclass(frozen=True)
class EnvOptions:
    """Options of the navigation env; every default is chosen for training the ``rrt`` mode."""

    max_steps: int | None = None
    """Step limit of an episode (truncation). None: ``max(50, ceil(time_factor * L / (v dt)))``
    with ``L`` the guide length (every leg for ``g-rrt``), ``v`` the robot's top speed
    (``max_speed``; racecar: ``max_wheel_speed`` times the wheel radius) and ``dt`` its agent
    step: ``time_factor`` times the time to follow the guide at full speed."""
    time_factor: float = 3.0
    """Multiple of the guide-following time that sets the default ``max_steps``."""
    observation: ObservationMode = "guided"
    """``"guided"``: state, progress and the next ``lookahead`` ball centres (plus rays);
    ``"paper"``: the bare product state ``(s_t, i_t)`` of the paper (plus rays)."""
    lookahead: int = 3
    """How many next r-ball centres the ``"guided"`` observation holds (0: none)."""
    lookahead_range: float | None = None
    """Scale of the ball offsets (clipped beyond it), metres. None: ``2 r (lookahead + 1)``."""
    rays: int = 0
    """Number of lidar-like rays in the observation (0: none)."""
    ray_range: float | None = None
    """Maximum ray range in metres. None: an eighth of the world's diagonal."""
    curriculum: float = 0.0
    """Probability that an episode starts at a uniformly drawn r-ball of the guide (not the
    last) with the progress index set to it. Evaluation must pass 0."""
    start_noise: float = 0.0
    """Radius (m) of a uniform perturbation of the start position; a perturbed start stays
    collision free and in the same regions as the nominal one (100 draws, else no noise)."""
    heading_noise: float = 0.0
    """Half-width (rad) of a uniform perturbation of the start heading (pi: any heading)."""
    handover: bool = True
    """Real starts where the mission hands the robot over (``envs.handover``: each preceding
    sub-task's guide entering its goal region, facing along it; the mission start with its
    heading for the first sub-task); needs the plan. False, or without a plan: the start of
    the sub-task's guide facing along it (the mission's start heading at the mission start)."""
    stall_steps: int = 0
    """End the episode after this many steps without a new r-ball (0: never)."""
    stall_penalty: float | None = None
    """Reward of a stall: None ends a stall as a truncation (value bootstrapped, no penalty);
    a number ends it as a termination with that reward (a failure the critic learns)."""
    dense_progress: bool = False
    """Pay the ``rrt``/``g-rrt`` gain on every step as the decrease of the continuous
    distance-to-go ``D_min`` of the next ball plus the distance to that ball's centre (a
    potential, so a round trip earns nothing), not only on entering a new ball."""
    min_forward: float | None = None
    """Robots driven by (forward, turn) actions (unicycle, racecar) only: map the policy's
    forward component from ``[-1, 1]`` onto ``[min_forward, 1]`` (e.g. 0.2: always creep
    forward, no parking or reversing). None: the action goes to the robot unchanged."""
    guide_feedforward: float | None = None
    """Add this share of the full command toward the guide's carrot (``envs.feedforward``;
    world-frame robots: to the whole action, (forward, turn) robots: to the turn) to the
    policy's action, clipped to ``[-1, 1]``: the policy learns a correction to following the
    guide. None: the action goes to the robot unchanged."""
    r_ball: float | None = None
    """Radius of the guide's r-balls. None: the plan's ``r_ball``, or the planner default
    (a fortieth of the world's diagonal, ``eta / 2``) without a plan."""
    rewards: RewardConfig = field(default_factory=RewardConfig)
    """Reward constants over the mode's defaults (see ``envs.rewards``)."""

    def __post_init__(self) -> None:
        def need(ok: bool, name: str, rule: str) -> None:
            if not ok:
                raise EnvConfigError(f"options.{name}", f"{rule}, got {getattr(self, name)!r}")

        def integer(name: str) -> bool:
            value = getattr(self, name)
            return isinstance(value, int | np.integer) and not isinstance(value, bool)

        def number(name: str) -> bool:
            value = getattr(self, name)
            ok = isinstance(value, int | float | np.number) and not isinstance(value, bool)
            return ok and math.isfinite(value)

        need(self.max_steps is None or integer("max_steps"), "max_steps", "must be an integer")
        need(self.max_steps is None or self.max_steps >= 1, "max_steps", "must be >= 1")
        need(number("time_factor") and self.time_factor > 0, "time_factor", "must be > 0")
        need(self.observation in ("guided", "paper"), "observation", "must be guided or paper")
        need(integer("lookahead") and self.lookahead >= 0, "lookahead", "must be an integer >= 0")
        need(integer("rays") and self.rays >= 0, "rays", "must be an integer >= 0")
        for name in ("lookahead_range", "ray_range", "r_ball"):
            value = getattr(self, name)
            need(value is None or (number(name) and value > 0), name, "must be > 0")
        need(number("curriculum") and 0 <= self.curriculum <= 1, "curriculum", "must be in [0, 1]")
        need(number("start_noise") and self.start_noise >= 0, "start_noise", "must be >= 0")
        need(
            number("heading_noise") and 0 <= self.heading_noise <= math.pi,
            "heading_noise",
            "must be in [0, pi]",
        )
        need(integer("stall_steps") and self.stall_steps >= 0, "stall_steps", "must be >= 0")
        need(isinstance(self.dense_progress, bool), "dense_progress", "must be true or false")
        need(
            self.stall_penalty is None or number("stall_penalty"), "stall_penalty", "must be finite"
        )
        need(
            self.min_forward is None or (number("min_forward") and -1 <= self.min_forward < 1),
            "min_forward",
            "must be in [-1, 1)",
        )
        need(
            self.guide_feedforward is None
            or (number("guide_feedforward") and 0 < self.guide_feedforward <= 1),
            "guide_feedforward",
            "must be in (0, 1]",
        )
        need(isinstance(self.rewards, RewardConfig), "rewards", "must be a RewardConfig")

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Every option name (the keyword arguments ``make_env`` accepts)."""
        return tuple(f.name for f in fields(cls))


def _options(options: EnvOptions | None, overrides: dict[str, Any]) -> EnvOptions:
    base = options if options is not None else EnvOptions()
    if not isinstance(base, EnvOptions):
        raise EnvConfigError("options", f"expected EnvOptions, got {type(base).__name__}")
    known = EnvOptions.field_names()
    for key in overrides:
        if key not in known:
            raise EnvConfigError(key, f"unknown env option; known: {', '.join(known)}")
    if "rewards" in overrides:
        overrides = {**overrides, "rewards": reward_config(overrides["rewards"])}
    return dataclasses.replace(base, **overrides) if overrides else base


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
    opts = _options(options, overrides)
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
    r_ball = opts.r_ball or (plan.r_ball if plan is not None else world.diagonal / 40.0)
    legs = build_course(world, spec.radius, subtasks, r_ball)
    heading = legs[0].headings[0]
    if len(spec.start) > world.dim and np.allclose(subtasks[0].start, start):
        heading = float(spec.start[world.dim])
    real = [Pose(np.asarray(subtasks[0].start, dtype=float), heading)]
    if plan is not None and opts.handover and not mode.whole_lasso:
        k = next((i for i, s in enumerate(plan.subtasks) if s is subtasks[0]), None)
        if k is not None:
            facing = float(spec.start[world.dim]) if len(spec.start) > world.dim else heading
            mission_start = Pose(start, facing)
            real = handover_poses(world, plan.subtasks, k, mission_start)
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
            starts=real,
            nba=plan.pruned if plan is not None else None,
            render_mode=render_mode,
            owns_robot=own,
        )
    except BaseException:
        if own:
            bot.close()
        raise


def build_course(
    world: World, radius: float, subtasks: Sequence[SubTask], r_ball: float
) -> list[Leg]:
    """One ``Leg`` (guide of ``r_ball`` balls, tracker, goal test) per sub-task, checked
    against ``world`` for a robot of ``radius``: points of the world's dimension, known goal
    regions, and a first start inside the bounds and collision free."""
    d = world.dim
    guides: list[Guide] = []
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
        guides.append(Guide.from_path(path, r_ball))
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
    for k, (sub, guide) in enumerate(zip(subtasks, guides, strict=True)):
        goal = RegionTest(world.regions[sub.goal]) if sub.goal else None
        headings = [heading_along(guide.centers[i:]) for i in range(guide.num_balls)]
        tracker = ProgressTracker(guide)
        legs.append(Leg(sub, guide, tracker, offset, sum(lengths[k + 1 :]), goal, headings))
        offset += guide.num_balls
    return legs


def split_subtask(subtask: SubTask, max_length: float) -> list[SubTask]:
    """``subtask`` cut into consecutive pieces of equal path length, at most ``max_length``
    metres each (shorter legs for very long guides: one agent per piece). Every piece but the
    last has no goal region (``goal == ""``: its episode succeeds in the last r-ball of its
    path) and stays in the sub-task's automaton state; the last piece keeps the goal and the
    transition. Indices are left as they are: renumber them if the pieces join a plan."""
    if not max_length > 0:
        raise EnvConfigError("max_length", f"must be > 0, got {max_length}")
    path = np.asarray(subtask.path, dtype=float)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    count = max(1, math.ceil(cum[-1] / max_length - 1e-9))
    cuts = np.linspace(0.0, cum[-1], count + 1)
    inner = [np.interp(cuts[1:-1], cum, path[:, j]) for j in range(path.shape[1])]
    knots = [path[0], *np.stack(inner, axis=1), path[-1]]
    pieces: list[SubTask] = []
    for k in range(count):
        between = path[(cum > cuts[k]) & (cum < cuts[k + 1])]
        piece = np.vstack([knots[k], between, knots[k + 1]])
        last = k == count - 1
        pieces.append(
            dataclasses.replace(
                subtask,
                start=piece[0].copy(),
                path=piece,
                goal=subtask.goal if last else "",
                next_nba_state=subtask.next_nba_state if last else subtask.nba_state,
            )
        )
    return pieces


def heading_along(path: np.ndarray) -> float:
    """Yaw of the first non-degenerate segment of ``path`` (0 for a single point)."""
    for p in path[1:]:
        d = p - path[0]
        if float(np.hypot(d[0], d[1])) > 1e-9:
            return math.atan2(float(d[1]), float(d[0]))
    return 0.0


def nominal_speed(robot: Robot) -> float:
    """The robot's top speed in m/s (``max_speed``; racecar: wheel speed times radius)."""
    params = robot.params
    if isinstance(params, RacecarParams):
        return float(params.max_wheel_speed * WHEEL_RADIUS)
    speed = getattr(params, "max_speed", None)
    return float(speed) if isinstance(speed, int | float) and speed > 0 else 1.0


def default_max_steps(legs: Sequence[Leg], robot: Robot, time_factor: float) -> int:
    """``max(50, ceil(time_factor * L / (v dt)))``: see ``EnvOptions.max_steps``."""
    length = sum(leg.guide.length for leg in legs)
    return max(50, math.ceil(time_factor * length / (nominal_speed(robot) * robot.dt)))


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
    # Checked by shape, not class: importing planner.decompose would pull in the planner.
    if all(hasattr(subtask, a) for a in ("start", "path", "goal", "nba_state", "next_nba_state")):
        return subtask
    raise EnvConfigError("subtask", f"expected a SubTask or an index, got {subtask!r}")


def register_env() -> None:
    """Register ``ltlnav/Nav-v0`` with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="envs.factory:make_env")


register_env()
