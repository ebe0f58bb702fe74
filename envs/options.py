"""``EnvOptions``: every option of the navigation env, documented where it is declared.

``make_env`` (``envs.factory``) takes them as an ``EnvOptions`` or as keyword overrides; the
mission's ``training.env`` section names the same fields, and a bundle records them
(``eval_env``) because several fix what an action means.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np

from envs.errors import EnvConfigError
from envs.observation import ObservationMode
from envs.rewards import RewardConfig, reward_config

FeedforwardLaw = Literal["heading", "pursuit"]
"""How ``EnvOptions.guide_feedforward`` turns a (forward, turn) robot."""

GoalJudge = Literal["region", "guide_end"]
"""When the region judge says a sub-task's goal is reached (``EnvOptions.goal_judge``)."""


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
    """Maximum ray range in metres. None: the robot's (``envs.rays.default_ray_range``: 3.5 s at
    its top speed), whatever the world's size."""
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
    """End the episode after this many steps without a new r-ball (0: never, unless
    ``stall_spacings`` is set)."""
    stall_spacings: float | None = None
    """End the episode when no new r-ball is reached in the time the robot needs to cover this
    many ball spacings (``2 r``) at its top speed, and never sooner than ``STALL_MIN_SECONDS``
    (``envs.factory.stall_window``): the window follows the world's ball spacing and the
    robot's speed and agent step. Only without ``stall_steps``. None: no such window."""
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
    residual_scale: float | None = None
    """With ``guide_feedforward``: the share of the command range the policy's correction may
    take where the feed-forward adds to it (world-frame robots: the whole action; (forward,
    turn) robots: the turn), in ``(0, 1]``; the policy's component is scaled by it before the
    addition. None: 1, a correction that can override the feed-forward."""
    feedforward_law: FeedforwardLaw = "heading"
    """How ``guide_feedforward`` turns a (forward, turn) robot: ``"heading"``, toward the carrot
    in proportion to the heading error; ``"pursuit"`` (robots with a minimum turning radius),
    pure pursuit of a point along the guide (``envs.feedforward``; with ``drivable_guide``,
    along the dense redrawn path)."""
    feedforward_slowdown: bool = False
    """With ``guide_feedforward`` and ``feedforward_law`` ``"heading"``: the feed-forward also
    lowers the forward command by the size of its turn command, no lower than the slowest
    forward speed (``min_forward``; without it, standing), reached at a heading error of 90
    degrees or more, so the robot turns on a tight circle where the guide turns back
    (``envs.feedforward``). False: the forward command is the policy's alone."""
    pursuit_lookahead: float | None = None
    """With ``feedforward_law`` ``"pursuit"``: how far ahead on the guide the pursued point
    runs, in minimum turning radii of the robot. None: ``envs.feedforward.PURSUIT_LOOKAHEAD``."""
    pursuit_tight_lookahead: float | None = None
    """With ``feedforward_law`` ``"pursuit"`` on a redrawn guide: the lookahead, in minimum
    turning radii, where the track from the robot's projection to the pursued point passes
    within ``envs.feedforward.TIGHT_SLACK`` turning radii of touching an obstacle (a narrow
    door): pursuit starts a turn about a lookahead early and cuts its inside. None: the
    lookahead everywhere."""
    drivable_guide: float | None = None
    """Robots with a minimum turning radius (racecar) only: redraw every guide as a path of
    Dubins arcs of this multiple (>= 1) of that radius, from the pose the mission hands the
    robot over in (``envs.drivable``), so that U-turns and corners are loops and curves the car
    can drive. None: the plan's polylines."""
    progress_window: int | None = None
    """Count an r-ball as reached only when it is at most this many balls past the progress
    index (``planner.guidance``), so a guide that comes back near itself (a drawn U-turn loop)
    cannot be cut short. None: any ball, the paper's ``D``."""
    r_ball: float | None = None
    """Radius of the guide's r-balls. None: the plan's ``r_ball``, or the planner default
    (a fortieth of the world's diagonal, ``eta / 2``) without a plan."""
    r_ball_within_clearance: bool = False
    """With ``r_ball`` None: no wider than the clearance the plan keeps from obstacles, so that no
    ball holds a point on the far side of a wall and progress never jumps through one (in a
    large world the plan's ``r_ball`` is wider than a door). False: the plan's ``r_ball``."""
    goal_judge: GoalJudge = "region"
    """``"region"``: the goal is reached when the sub-task's goal region contains the robot's
    point (the guide's last r-ball for a sub-task without one); ``"guide_end"``: when the point
    is in the guide's last r-ball, ``D = 0``, as Cai et al. judge it. The automaton judge
    (``tl``, ``g-rrt``) ignores it."""
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
        need(
            self.goal_judge in ("region", "guide_end"),
            "goal_judge",
            "must be region or guide_end",
        )
        need(integer("lookahead") and self.lookahead >= 0, "lookahead", "must be an integer >= 0")
        need(integer("rays") and self.rays >= 0, "rays", "must be an integer >= 0")
        for name in (
            "lookahead_range",
            "ray_range",
            "r_ball",
            "pursuit_lookahead",
            "pursuit_tight_lookahead",
            "residual_scale",
        ):
            value = getattr(self, name)
            need(value is None or (number(name) and value > 0), name, "must be > 0")
        need(
            self.residual_scale is None or not number("residual_scale") or self.residual_scale <= 1,
            "residual_scale",
            "must be <= 1",
        )
        need(number("curriculum") and 0 <= self.curriculum <= 1, "curriculum", "must be in [0, 1]")
        need(number("start_noise") and self.start_noise >= 0, "start_noise", "must be >= 0")
        need(
            number("heading_noise") and 0 <= self.heading_noise <= math.pi,
            "heading_noise",
            "must be in [0, pi]",
        )
        need(integer("stall_steps") and self.stall_steps >= 0, "stall_steps", "must be >= 0")
        need(
            self.stall_spacings is None or (number("stall_spacings") and self.stall_spacings > 0),
            "stall_spacings",
            "must be > 0",
        )
        need(
            not (self.stall_steps and self.stall_spacings is not None),
            "stall_spacings",
            "set stall_steps or stall_spacings, not both",
        )
        need(isinstance(self.dense_progress, bool), "dense_progress", "must be true or false")
        need(
            isinstance(self.r_ball_within_clearance, bool),
            "r_ball_within_clearance",
            "must be true or false",
        )
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
        need(
            self.progress_window is None
            or (integer("progress_window") and self.progress_window >= 1),
            "progress_window",
            "must be an integer >= 1",
        )
        need(
            self.feedforward_law in ("heading", "pursuit"),
            "feedforward_law",
            "must be heading or pursuit",
        )
        need(
            isinstance(self.feedforward_slowdown, bool),
            "feedforward_slowdown",
            "must be true or false",
        )
        need(
            self.drivable_guide is None or (number("drivable_guide") and self.drivable_guide >= 1),
            "drivable_guide",
            "must be >= 1 (a multiple of the robot's minimum turning radius)",
        )
        need(isinstance(self.rewards, RewardConfig), "rewards", "must be a RewardConfig")

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Every option name (the keyword arguments ``make_env`` accepts)."""
        return tuple(f.name for f in fields(cls))


def options_with(options: EnvOptions | None, overrides: dict[str, Any]) -> EnvOptions:
    """``options`` (default ``EnvOptions()``) with keyword ``overrides`` checked and applied."""
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
