"""The mission's ``training:`` section.

``TrainingSpec`` is what a user may set: the algorithm, the budget, evaluation, the reward mode
and its constants, env options and stable-baselines3 hyperparameters under their RL-Zoo names
(checked per algorithm: an unknown key is an error naming it and listing the valid ones).
Reward and env defaults are not repeated here: an empty ``reward.constants`` or ``env`` takes
``envs.rewards``' and ``envs.options.EnvOptions``' own defaults.

One training job of a sub-task is ``workers.jobs.SubtaskJob``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from envs.errors import EnvConfigError
from envs.observation import HEADING_FEATURES
from envs.options import EnvOptions
from envs.rewards import REWARD_MODES, RewardConfig, reward_mode
from planner.geometry.shape_spec import raise_problems
from workers.hyperparameters import (
    DEFAULT_POLICY_KWARGS,
    HYPERPARAMETERS,
    actor_option_problems,
    backend_problems,
    env_count_problems,
    policy_kwargs_problems,
)

Algorithm = Literal["sac", "td3", "ddpg", "ppo"]
Backend = Literal["sb3", "sbx"]
RewardModeName = Literal["rrt", "rrt-paper", "g-rrt", "ned", "tl"]

TRAINING_ENV_DEFAULTS: dict[str, Any] = {
    "curriculum": 0.7,
    "rays": 16,
    "r_ball_within_clearance": True,
}
"""Env options the ``shaped`` protocol uses unless ``env`` sets them (measured in
``bench/LEARNING.md``): 70 % of training episodes start at a random r-ball of the guide with
the progress index to match, so the far end of a long guide is trained from the start
(evaluations always use 0); 16 lidar-like rays in the observation (training and evaluation
alike), so that keeping off a box is a function of what the robot senses, not of a memorised
map; r-balls no wider than the plan's clearance, so none reaches through a wall (in a 54 m
world the plan's 1.9 m ball past a door held the robot before the wall): the zero action on the
tuning worlds of ``bench/zero_grid.py ROBOT --seeds 0 40`` (20 starts a sub-task) holds 106 of
106 sub-tasks for every robot with it, against 105 (point, racecar) and 106 (point in 3D,
quadrotor) without it; the unicycle 266 of 266 on seeds 0-99 against 261. Its effect on what
SAC learns is measured on the racecar's report missions only: rooms 1002's three trained
sub-tasks met their targets with it; 1001's first fails either way (8 % of the missions with it,
26 % without, one seed on one machine)."""

STALL_ENV_DEFAULTS: dict[str, Any] = {"stall_steps": 30}
"""Training defaults of the ``shaped`` protocol: an episode that reaches no new r-ball for 30
steps ends as a failure with the mode's crash reward (``stall_penalty``), so leaving the guide
costs what a crash costs and the off-guide wandering never fills the replay buffer. A mission's
``stall_steps`` or ``stall_spacings`` (the window in the robot's terms) replaces it. The
window in the robot's terms (``stall_spacings`` 4) cut none of the robots' own controllers
short where 30 steps cut a third (``bench/stall_window.py``), but trained worse on the only
report sub-task that needed training (racecar 1001, seeds 0 and 1: 36.5 and 25 % against 63
and 35 %, ``bench/LEARNING.md``), so it is not the default. Evaluations never stop a stalled
episode."""

Protocol = Literal["shaped", "paper"]
"""The env every reward mode trains and is evaluated in (``TrainingSpec.protocol``)."""

PAPER_ENV: dict[str, Any] = {
    "observation": "paper",
    "rays": 0,
    "curriculum": 0.0,
    "goal_judge": "guide_end",
}
"""The ``paper`` protocol, Cai et al.'s env as published: the observation is the robot's state
and the product state ``(s_t, i_t)`` (no ball offsets, no rays), episodes start at the real
start (no curriculum), nothing ends an episode early but a crash or the goal, no action
shaping (no stall, ``min_forward``, feed-forward or redrawn guide), and a sub-task is met at
``D = 0`` (the guide's last r-ball)."""

HEADING_ENV_DEFAULTS: dict[str, Any] = {"min_forward": 0.2}
"""Defaults for robots driven by (forward, turn) actions, in training and evaluation alike (it
changes what an action means): the forward command maps onto [0.2, 1] of the top speed, which
removes the parking optimum; without it every measured agent learned to stand still."""


GUIDE_ENV_DEFAULTS: dict[str, dict[str, Any]] = {
    "point": {"guide_feedforward": 1.0},
    "quadrotor": {"guide_feedforward": 1.0},
    "unicycle": {"guide_feedforward": 1.0, "feedforward_slowdown": True},
    "racecar": {
        "drivable_guide": 1.45,
        "guide_feedforward": 1.0,
        "feedforward_law": "pursuit",
        "pursuit_tight_lookahead": 0.6,
        "progress_window": 2,
    },
}
"""Defaults per robot of the ``shaped`` protocol, in training and evaluation alike (they change
what an action means and which guide the reward follows). Measured in ``bench/LEARNING.md``:

* point: the acceleration that brings it to top speed toward the guide's point one braking
  length ahead (``envs.feedforward.velocity_command``): on generated 21 x 21 m mazes of 0.3 m
  walls (``<>(g1 && <>g2)``, guides up to 64 m), tuned on maze seed 1 and reported on seeds
  100-104, the zero action alone meets 100 % of 50 trials on all ten sub-tasks; without it a
  61 m guide stayed at 0 % to 55k steps (the agent learned to stop short of the goal).
* quadrotor: the full velocity command toward the guide's carrot is added to the policy's
  action (``envs.feedforward``), which then learns the correction: phi_1,inf sub-task 0 from
  0 % at 40k steps to 100 % at 5k; the feed-forward alone (a zero policy) crashes there.
* racecar: every guide is redrawn as Dubins arcs of 1.45 times its turning radius (0.9 m)
  from the hand-over pose (``envs.drivable``), so the U-turns at g2 and g3 become loops it can
  drive; the feed-forward turn is pure pursuit along that guide; a ball counts only two past
  the progress index, so the start of a loop is not taken for its end. Without them the
  U-turn sub-tasks stayed at 0-69 % up to 150k steps; with them the zero action makes every
  sub-task of racecar phi_2,fin and 100 % of its missions, and each needs all three. The
  factor was fitted on that example; on the generated tuning worlds of ``bench/zero_grid.py
  racecar --env '{"drivable_guide": F}'`` the zero action holds 48 of 52 sub-tasks at F = 1.2,
  1.45 and 1.7, and 46 at 2.0. Where the track ahead passes within 0.12 m of touching (a
  narrow door), pursuit aims 0.6 turning radii ahead instead of 1.3, so it starts a turn past
  the door later and cuts less of it: on tuning seeds 0-69 (20 starts a sub-task) 182 -> 185 of
  186 sub-tasks held, 68 -> 69 of 70 worlds (seeds 42 and 66, 0.77 and 0.88 m doors; 0.6 and
  0.9 were tried on those two alone, 0.6 kept before the whole grid ran); on seeds 70-99,
  measured once after the choice, 76 -> 78 of 80 and 27 -> 28 of 30 worlds.

* unicycle: the turn toward the guide's point ``HEADING_LOOKAHEAD`` seconds ahead
  (``envs.feedforward.heading_direction``): on the tuning worlds of ``bench/zero_grid.py`` the
  zero action alone holds 47 of 52 sub-tasks (the carrot two balls ahead, no default: 16), and
  every sub-task of ``examples/car-phi2-fin.yaml``. With ``feedforward_slowdown`` it also
  slows down as it turns, so a guide that turns back at a hand-over becomes a tight U-turn:
  ``bench/zero_grid.py unicycle --seeds 0 40`` 102 -> 106 of 106 sub-tasks held (36 -> 40 of
  40 worlds); on seeds 40-99, not looked at while choosing it, 154 -> 155 of 160 (seed 66
  loses a sub-task that cuts the corner behind a door, four others gain)."""


class RewardSpec(BaseModel):
    """Reward mode and constants (constants not given take the mode's defaults)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    mode: RewardModeName = Field(
        "rrt",
        description="'rrt' (default, the guide-distance reward), 'rrt-paper' (Cai et al.'s exact "
        "reward), 'g-rrt' (one guide for the whole lasso), 'ned' (negative distance), 'tl' "
        "(sparse automaton reward). See envs.rewards.",
    )
    constants: dict[str, float] = Field(
        default_factory=dict,
        description="Reward constants over the mode's defaults: crash, goal, progress, "
        "step_cost, distance (each mode uses some of them).",
    )

    def config(self) -> RewardConfig:
        """The constants as an ``envs.rewards.RewardConfig``."""
        return RewardConfig(**self.constants)

    @model_validator(mode="after")
    def _known(self) -> RewardSpec:
        known = [f.name for f in dataclasses.fields(RewardConfig)]
        problems = [
            (f"constants.{k}", f"unknown reward constant; known: {', '.join(known)}")
            for k in self.constants
            if k not in known
        ]
        raise_problems(problems)
        try:
            reward_mode(self.mode, self.config())
        except EnvConfigError as err:
            raise_problems([(err.field.replace("rewards.", "constants."), err.reason)])
        assert self.mode in REWARD_MODES
        return self


class TrainingSpec(BaseModel):
    """How to train every sub-task of a mission (the mission's ``training:`` section)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    algorithm: Algorithm = Field("sac", description="stable-baselines3 algorithm.")
    n_timesteps: int = Field(150_000, ge=1, description="Budget of env steps per sub-task.")
    eval_freq: int = Field(5_000, ge=1, description="Env steps between periodic evaluations.")
    eval_episodes: int = Field(
        50,
        ge=1,
        description="Episodes of each periodic evaluation (50: the early stop at 95 % "
        "then means 48 of 50; 19 of 20 stopped measured runs at 87-89 % over 200 trials).",
    )
    eval_lanes: int = Field(
        10,
        ge=1,
        le=64,
        description="Copies of the evaluation env (and of the mission env, for whole-mission "
        "rollouts) that every evaluation steps in lockstep, one batched policy call for all of "
        "them (1: one episode after another).",
    )
    final_eval_episodes: int = Field(
        200, ge=1, description="Episodes of the final sub-task evaluation (200 in the paper)."
    )
    target_success: float = Field(
        0.95,
        gt=0,
        le=1,
        description="Stop early once a periodic evaluation reaches this rate and the final "
        "evaluation (final_eval_episodes), run at that point, confirms it.",
    )
    plateau_evals: int | None = Field(
        None,
        ge=1,
        description="Stop training once the best periodic rate is >= plateau_from and this "
        "many evaluations in a row, their median within 2 standard errors of plateau_from (a "
        "fall is no plateau), have not beaten it; keep the best's policy (None: never).",
    )
    plateau_from: float = Field(
        0.9,
        ge=0,
        le=1,
        description="The best periodic success rate from which plateau_evals stops training: "
        "below it a flat curve is a sub-task still to learn (SAC's often stay flat for tens of "
        "thousands of steps before they rise), which trains on.",
    )
    actor_burn_in: int = Field(
        0,
        ge=0,
        description="Env steps at the start during which only the critic learns: the actor "
        "and SAC's entropy coefficient are not updated, so a residual agent keeps its "
        "controller meanwhile (sb3's off-policy algorithms).",
    )
    actor_average_steps: int | None = Field(
        None,
        ge=1,
        description="Time constant, in env steps, of an average of the actor's weights that "
        "evaluations measure and the job keeps, against a policy that collapses between them "
        "(None: the last weights; sb3's off-policy algorithms; restarts when a job resumes).",
    )
    checkpoint_freq: int | None = Field(
        None, ge=1, description="Env steps between checkpoints (None: every eval_freq steps)."
    )
    mission_episodes: int = Field(
        100, ge=1, description="Whole-mission rollouts of the concatenated policy."
    )
    cycles: int = Field(3, ge=1, description="Suffix cycles of a whole-mission rollout.")
    mission_target: float = Field(
        0.9,
        gt=0,
        le=1,
        description="Whole-mission success rate the pipeline aims at: below it, every sub-task "
        "the rollouts failed in trains on from the poses the rollouts handed it the robot in "
        "(workers.handover_repair), for handover_rounds rounds.",
    )
    handover_rounds: int = Field(
        2, ge=0, description="Rounds of hand-over repair at most (0: none; see mission_target)."
    )
    handover_steps: int = Field(
        30_000, ge=1, description="Budget of env steps of one sub-task's hand-over repair."
    )
    eval_start_noise: float = Field(
        0.2,
        ge=0,
        description="Start perturbation (m) of every evaluation episode and mission rollout, "
        "and of training starts unless training.env sets start_noise: the dynamics and a "
        "deterministic policy are otherwise noise free, so N identical trials would measure "
        "one trajectory.",
    )
    eval_heading_noise: float = Field(
        0.4, ge=0, le=3.141592653589793, description="Start heading perturbation (rad), likewise."
    )
    seed: int = Field(0, ge=0, description="Seed of the agents and the env resets.")
    torch_threads: int = Field(
        1, ge=1, description="torch (and XLA, backend sbx) threads per job; more is slower shared."
    )
    n_envs: int = Field(
        1,
        ge=1,
        le=16,
        description="Copies of the training env one learner steps in turn, one batched policy "
        "call for all (a DummyVecEnv in the job's process). Off-policy agents keep their "
        "gradient steps per env step: train_freq, eval_freq and checkpoint_freq must be "
        "multiples of it.",
    )
    backend: Backend = Field(
        "sb3",
        description="Learner: 'sb3' (stable-baselines3, default) or 'sbx' (SBX: SAC on JAX, "
        "needs the 'sbx' extra; the same hyperparameters and the same SB3 archives, Adam's "
        "state not kept across a resume; XLA gets torch_threads threads too).",
    )
    reward: RewardSpec = Field(default_factory=lambda: RewardSpec(), description="Reward.")
    protocol: Protocol = Field(
        "shaped",
        description="'shaped' (default): every reward mode gets the same env, with the "
        "measured defaults (rays, curriculum, stall, min_forward, the robot's feed-forward); "
        "'paper': Cai et al.'s env as published (state and (s_t, i_t) only, no curriculum, no "
        "stall, no action shaping, success at D = 0). env overrides either.",
    )
    env: dict[str, Any] = Field(
        default_factory=dict,
        description="envs.options.EnvOptions fields (max_steps, observation, lookahead, rays, "
        "curriculum, stall_steps, min_forward, ...); unset ones take EnvOptions' defaults.",
    )
    hyperparams: dict[str, Any] = Field(
        default_factory=dict,
        description="stable-baselines3 hyperparameters by RL-Zoo name (HYPERPARAMETERS lists "
        "the valid ones per algorithm); policy_kwargs defaults to DEFAULT_POLICY_KWARGS.",
    )

    @field_validator("env")
    @classmethod
    def _env_fields(cls, env: dict[str, Any]) -> dict[str, Any]:
        known = [n for n in EnvOptions.field_names() if n != "rewards"]
        problems = [
            (k, f"unknown env option; known: {', '.join(known)}") for k in env if k not in known
        ]
        raise_problems(problems)
        try:
            EnvOptions(**env)
        except EnvConfigError as err:
            raise_problems([(err.field.removeprefix("options."), err.reason)])
        return env

    @field_validator("hyperparams")
    @classmethod
    def _hyperparams(cls, hyperparams: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        algorithm = info.data.get("algorithm")
        if algorithm not in HYPERPARAMETERS:
            return hyperparams  # the algorithm itself is reported invalid
        valid = HYPERPARAMETERS[algorithm]
        problems: list[tuple[str, str]] = []
        for key, value in hyperparams.items():
            if key not in valid:
                problems.append(
                    (
                        key,
                        f"unknown {algorithm} hyperparameter {key!r}; valid: "
                        f"{', '.join(sorted(valid))}",
                    )
                )
            elif key == "policy_kwargs":
                problems.extend(policy_kwargs_problems(value))
        raise_problems(problems)
        return hyperparams

    @model_validator(mode="after")
    def _learner(self) -> TrainingSpec:
        raise_problems(backend_problems(self.backend, self.algorithm, self.hyperparams))
        actor = self.model_dump(include={"actor_burn_in", "actor_average_steps"})
        raise_problems(actor_option_problems(actor, self.backend, self.algorithm))
        counts = {"eval_freq": self.eval_freq, "checkpoint_freq": self.checkpoint_freq}
        raise_problems(env_count_problems(self.n_envs, self.algorithm, self.hyperparams, counts))
        return self

    def env_options(self, model: str, **overrides: Any) -> EnvOptions:
        """The training env options of a ``model`` robot with the reward constants
        (``overrides`` replace fields)."""
        fields = {**self._resolved_env(model), **overrides}
        return EnvOptions(**fields, rewards=self.reward.config())

    def eval_env_options(self, model: str) -> EnvOptions:
        """The env options of evaluations and mission rollouts: the training ones from the
        sub-task's real start (no curriculum, no stall termination), with the evaluation start
        noise and the default reward constants (only the goal judge matters)."""
        fields = {
            **self._resolved_env(model),
            "curriculum": 0.0,
            "stall_steps": 0,
            "stall_spacings": None,
            "start_noise": self.eval_start_noise,
            "heading_noise": self.eval_heading_noise,
        }
        return EnvOptions(**fields)

    def _resolved_env(self, model: str) -> dict[str, Any]:
        """``env`` over the protocol's defaults for a ``model`` robot: ``paper`` takes
        ``PAPER_ENV``; ``shaped`` the measured training defaults, the same for every reward
        mode (only the reward differs). Either way training starts are spread like the
        evaluation's (``eval_start_noise``, ``eval_heading_noise``), so a policy is reported on
        the start distribution it was trained on."""
        spread = {"start_noise": self.eval_start_noise, "heading_noise": self.eval_heading_noise}
        if self.protocol == "paper":
            return {**spread, **PAPER_ENV, **self.env}
        defaults = {**spread, **TRAINING_ENV_DEFAULTS}
        if model in HEADING_FEATURES:
            defaults.update(HEADING_ENV_DEFAULTS)
        defaults.update(GUIDE_ENV_DEFAULTS.get(model, {}))
        crash = reward_mode(self.reward.mode, self.reward.config()).crash
        defaults["stall_penalty"] = crash
        if not {"stall_steps", "stall_spacings"} & set(self.env):
            defaults.update(STALL_ENV_DEFAULTS)
        return {**defaults, **self.env}

    def policy_kwargs(self) -> dict[str, Any]:
        """``policy_kwargs`` over ``DEFAULT_POLICY_KWARGS`` (activation still a name)."""
        given = self.hyperparams.get("policy_kwargs") or {}
        return {**DEFAULT_POLICY_KWARGS, **given}
