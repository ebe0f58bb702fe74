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
from workers.env_defaults import (
    GUIDE_ENV_DEFAULTS,
    HEADING_ENV_DEFAULTS,
    PAPER_ENV,
    STALL_ENV_DEFAULTS,
    TRAINING_ENV_DEFAULTS,
    Protocol,
)
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
        6,
        ge=1,
        description="Stop training once the best periodic rate is >= plateau_from and this "
        "many evaluations in a row, their median within 2 standard errors of plateau_from (a "
        "fall is no plateau), have not beaten it; the kept policy is chosen as after the "
        "budget (see pick_candidates). None: never. 6 with pick_candidates 3 made the same or "
        "better missions than without either in 0.67-0.90 of the wall time on 3 fresh seeds of "
        "the racecar's forest (bench/LEARNING.md).",
    )
    plateau_from: float = Field(
        0.9,
        ge=0,
        le=1,
        description="The best periodic success rate from which plateau_evals stops training: "
        "below it a flat curve is a sub-task still to learn (SAC's often stay flat for tens of "
        "thousands of steps before they rise), which trains on.",
    )
    pick_candidates: int | None = Field(
        3,
        ge=1,
        description="When the budget runs out or a plateau stops training, evaluate the "
        "policies of this many best periodic evaluations and the last one on "
        "final_eval_episodes episodes of seeds of their own and keep the best (None: keep the "
        "best periodic evaluation's if it beat the last; 50 episodes rank by luck).",
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
