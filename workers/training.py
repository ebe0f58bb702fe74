"""Train one sub-task's agent: ``train_subtask(job, out_dir) -> TrainResult``.

A plain function that the Celery task, the CLI pipeline and the tests call the same way. It is
idempotent: ``out_dir`` holds checkpoints (model and replay buffer), ``evaluations.npz``, the
logs (CSV and TensorBoard) and ``result.json``;
a restarted job resumes from the newest checkpoint (``num_timesteps`` restored, no step redone
beyond the checkpoint) and a finished one returns its stored result.

Layout of ``out_dir``: ``checkpoints/model_<steps>_steps.zip`` (+ ``model_replay_buffer_...``),
``evaluations.npz``, ``logs/run_<steps>/`` (one folder per (re)start), ``model.zip`` (the final
policy) and ``result.json``.
"""

from __future__ import annotations

import json
import pickle
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv

from envs.factory import make_env
from envs.handover import Pose
from envs.nav_env import NavEnv
from planner.errors import LtlnavError
from planner.plan import MissionPlan
from planner.serialize import plan_from_dict
from workers.callbacks import (
    ProgressFn,
    PruneCheckpoints,
    ReportProgress,
    ResumableEvalCallback,
    StopFn,
    StopOnRequest,
    StopOnSuccessRate,
    checkpoints,
    prune_checkpoints,
)
from workers.evaluation import SubtaskEvaluation, evaluate_subtask
from workers.mission import MissionSpec, parse_mission
from workers.residual import recorded_start, start_check, zero_output_layer
from workers.training_spec import StartPose, SubtaskJob, TrainingSpec

ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO}
"""stable-baselines3 classes by ``training.algorithm`` name."""

ACTIVATION_MODULES: dict[str, type[torch.nn.Module]] = {
    "relu": torch.nn.ReLU,
    "tanh": torch.nn.Tanh,
    "elu": torch.nn.ELU,
    "leaky_relu": torch.nn.LeakyReLU,
    "gelu": torch.nn.GELU,
    "silu": torch.nn.SiLU,
}

Stopped = Literal["budget", "target", "cancelled"]


class TrainingError(LtlnavError):
    """A training job that cannot run as asked (bad sub-task index, unusable plan)."""


@dataclass
class TrainResult:
    """What a training job produced."""

    subtask: int
    seed: int
    model_path: str
    """The final policy (an SB3 .zip), or the last checkpoint of a cancelled job."""
    steps: int
    """Env steps trained in total (restored ones included)."""
    resumed_from: int
    """Steps restored from a checkpoint at the start of this call (0: fresh start)."""
    stopped: Stopped
    """Why training ended: the budget, the target success rate, or a cancel request."""
    policy_steps: int | None = None
    """Steps of the policy kept when the budget ran out before the target: that of the best
    periodic evaluation (the first with the highest success rate), if better than the last one;
    None: the policy at ``steps``."""
    curve: list[tuple[int, float]] = field(default_factory=list)
    """``(steps, success rate)`` of every periodic evaluation (and of the start check at step 0
    of a residual agent, ``workers.residual``)."""
    final: dict[str, Any] | None = None
    """``SubtaskEvaluation.to_json()`` over ``final_eval_episodes`` (None when cancelled)."""
    seconds: float = 0.0
    """Wall time of this call."""
    repairs: int = 0
    """Hand-over repair rounds the policy went through (``workers.handover_repair``); then
    ``final`` is measured from the poses the mission's rollouts handed the sub-task over in."""

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["curve"] = [list(p) for p in self.curve]
        return out

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> TrainResult:
        doc = dict(doc)
        doc["curve"] = [(int(s), float(r)) for s, r in doc.get("curve", [])]
        return cls(**doc)


def subtask_env(
    mission: MissionSpec,
    plan: MissionPlan,
    training: TrainingSpec,
    subtask: int,
    evaluation: bool = False,
    starts: Sequence[StartPose] | None = None,
) -> NavEnv:
    """The env of ``subtask`` as trained (or, with ``evaluation``, as evaluated: see
    ``TrainingSpec.eval_env_options``), from ``starts`` in place of the real starts when given;
    ``g-rrt`` drives the whole lasso whatever ``subtask``."""
    mode = training.reward.mode
    model = mission.robot.model
    options = training.eval_env_options(model) if evaluation else training.env_options(model)
    target = None if mode == "g-rrt" else plan.subtasks[subtask]
    poses = None
    if starts is not None:
        poses = [Pose(np.asarray(p.position, dtype=float), p.heading) for p in starts]
    world = mission.build_world()
    return make_env(mission, target, mode, world=world, plan=plan, options=options, starts=poses)


def hyperparameters(training: TrainingSpec, action_dim: int) -> dict[str, Any]:
    """The SB3 constructor keywords of ``training.hyperparams`` (RL-Zoo names mapped)."""
    params = {k: v for k, v in training.hyperparams.items() if k not in ("noise_type", "noise_std")}
    if training.algorithm != "ppo" and "buffer_size" not in params:
        # SB3's default (1e6) is larger than any budget here and every checkpoint pickles the
        # whole preallocated buffer: never keep more transitions than the job can collect.
        params["buffer_size"] = training.n_timesteps
    kwargs = training.policy_kwargs()
    kwargs["activation_fn"] = ACTIVATION_MODULES[kwargs["activation_fn"]]
    params["policy_kwargs"] = kwargs
    if isinstance(params.get("train_freq"), list):
        params["train_freq"] = (int(params["train_freq"][0]), str(params["train_freq"][1]))
    noise = training.hyperparams.get("noise_type")
    if noise is not None:
        std = float(training.hyperparams.get("noise_std", 0.1))
        cls = NormalActionNoise if noise == "normal" else OrnsteinUhlenbeckActionNoise
        params["action_noise"] = cls(np.zeros(action_dim), std * np.ones(action_dim))
    return params


def _load_job(job: SubtaskJob) -> tuple[MissionSpec, MissionPlan]:
    mission = parse_mission(job.mission)
    try:
        plan = plan_from_dict(job.plan)
    except (KeyError, TypeError, ValueError) as err:
        raise TrainingError(f"the job's plan document is malformed: {err!r}") from err
    if not 0 <= job.subtask < len(plan.subtasks):
        raise TrainingError(
            f"sub-task {job.subtask} does not exist: the plan has {len(plan.subtasks)}"
        )
    return mission, plan


def train_subtask(
    spec: SubtaskJob,
    out_dir: str | Path,
    on_progress: ProgressFn | None = None,
    should_stop: StopFn | None = None,
) -> TrainResult:
    """Train (or resume training) the agent of ``spec.subtask`` into ``out_dir``.

    ``on_progress(steps, success_rate, total)`` is called about once a second and after every
    evaluation; ``should_stop()`` is asked about twice a second and a True ends the job after a
    checkpoint (``stopped="cancelled"``). Stops early when a periodic evaluation reaches
    ``target_success`` and the final evaluation (``final_eval_episodes``), run then, confirms
    it; else training goes on. Deterministic for ``spec.seed`` on one machine.
    """
    t0 = time.monotonic()
    out = Path(out_dir)
    training = spec.training
    stored = out / "result.json"
    if stored.is_file():
        done = TrainResult.from_json(json.loads(stored.read_text()))
        if done.steps >= training.n_timesteps or _meets(done, training.target_success):
            return done
    mission, plan = _load_job(spec)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(training.torch_threads)
    k, starts = spec.subtask, spec.starts
    env = DummyVecEnv([lambda: Monitor(subtask_env(mission, plan, training, k, False, starts))])
    eval_env = DummyVecEnv([lambda: Monitor(subtask_env(mission, plan, training, k, True, starts))])
    env.seed(spec.seed)
    eval_env.seed(spec.seed + 1)
    test_env = subtask_env(mission, plan, training, k, True, starts)
    folder = out / "checkpoints"
    warm = Path(spec.warm_start) if spec.warm_start is not None else None
    residual = training.env_options(mission.robot.model).guide_feedforward is not None
    model, resumed = _model(training, env, folder, spec.seed, warm, residual)
    fresh = resumed == 0 and warm is None

    def act(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    def final_evaluation() -> SubtaskEvaluation:
        return evaluate_subtask(act, test_env, training.final_eval_episodes, seed=spec.seed + 2)

    def quick_evaluation() -> SubtaskEvaluation:
        return evaluate_subtask(act, test_env, training.eval_episodes, seed=spec.seed + 1)

    model.set_logger(configure(str(out / "logs" / f"run_{resumed}"), ["csv", "tensorboard"]))
    evaluation = ResumableEvalCallback(
        eval_env,
        n_eval_episodes=training.eval_episodes,
        eval_freq=training.eval_freq,
        log_path=str(out),
        best_model_save_path=None,
        deterministic=True,
        warn=False,
        verbose=0,
        callback_after_eval=StopOnSuccessRate(training.target_success, final_evaluation),
        best_path=out / "best_model.zip",
    )
    evaluation.restore(resumed)
    start = None
    if residual and fresh:
        start = start_check(quick_evaluation, final_evaluation, training.target_success, out)
        evaluation.offer(model, 0, start.success_rate)
    begun = recorded_start(out)
    evaluation.start_rate = begun.success_rate if begun is not None else None
    every = training.checkpoint_freq or training.eval_freq
    callbacks: list[BaseCallback] = [
        evaluation,
        CheckpointCallback(every, str(folder), name_prefix="model", save_replay_buffer=True),
        PruneCheckpoints(folder, every),
    ]
    cancel = StopOnRequest(should_stop) if should_stop is not None else None
    if cancel is not None:
        callbacks.append(cancel)
    if on_progress is not None:
        callbacks.append(ReportProgress(on_progress, training.n_timesteps, evaluation))
        on_progress(resumed, evaluation.last_success_rate, training.n_timesteps)
    remaining = training.n_timesteps - resumed
    cancelled = should_stop is not None and should_stop()
    at_start = start is not None and start.confirmed is not None
    if remaining > 0 and not cancelled and not at_start:
        model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=False)
        cancelled = cancel is not None and cancel.stopped
    steps = int(model.num_timesteps)
    _checkpoint(model, folder, steps)
    prune_checkpoints(folder)
    stopper = evaluation.callback
    assert isinstance(stopper, StopOnSuccessRate)
    stopped: Stopped = "budget"
    if cancelled:
        stopped = "cancelled"
    elif stopper.reached or at_start:
        stopped = "target"
    result = TrainResult(
        subtask=spec.subtask,
        seed=spec.seed,
        model_path=str(folder / f"model_{steps}_steps.zip"),
        steps=steps,
        resumed_from=resumed,
        stopped=stopped,
        curve=evaluation.success_curve,
    )
    if stopped == "budget":
        model, result.policy_steps = keep_best_policy(model, evaluation, training, env)
    if stopped != "cancelled":
        final = out / "model.zip"
        model.save(final)
        confirmed = stopper.confirmed if stopped == "target" else None
        if at_start and start is not None:
            confirmed = start.confirmed
        result.final = (confirmed or final_evaluation()).to_json()
        result.model_path = str(final)
    env.close()
    eval_env.close()
    test_env.close()
    result.seconds = time.monotonic() - t0
    if on_progress is not None:
        on_progress(steps, evaluation.last_success_rate, training.n_timesteps)
    if stopped != "cancelled":
        stored.write_text(json.dumps(result.to_json(), indent=1))
    return result


def _meets(result: TrainResult, target: float) -> bool:
    """Whether a stored result stopped at the target and its final evaluation reaches
    ``target`` (a result below it, e.g. after ``target_success`` was raised, trains on)."""
    rate = (result.final or {}).get("success_rate")
    return result.stopped == "target" and (rate is None or rate >= target)


def _model(
    training: TrainingSpec,
    env: DummyVecEnv,
    folder: Path,
    seed: int,
    warm: Path | None = None,
    residual: bool = False,
) -> tuple[BaseAlgorithm, int]:
    """The newest checkpoint in ``folder`` with its replay buffer; else, with ``warm`` (a
    finished job's folder), its policy and newest replay buffer at step 0; else a fresh model
    (``residual``: its action output starts at zero, ``workers.residual``)."""
    cls = ALGORITHMS[training.algorithm]
    found = checkpoints(folder)
    if not found and warm is not None:
        return _warm_model(cls, env, warm, seed), 0
    for path, buffer, steps in found:
        try:
            model = cls.load(path, env=env, device="cpu")
            if buffer is not None and isinstance(model, OffPolicyAlgorithm):
                model.load_replay_buffer(buffer)
        except (OSError, EOFError, ValueError, RuntimeError, pickle.UnpicklingError) as err:
            # a checkpoint cut short by the kill that restarted this job: use an older one
            warnings.warn(f"skipping unreadable checkpoint {path.name}: {err}", stacklevel=2)
            continue
        model.num_timesteps = steps
        return model, steps
    shape = env.action_space.shape
    assert shape is not None
    params = hyperparameters(training, int(np.prod(shape)))
    model = cls("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **params)
    if residual:
        zero_output_layer(model)
    return model, 0


def _warm_model(cls: type[BaseAlgorithm], env: DummyVecEnv, warm: Path, seed: int) -> BaseAlgorithm:
    policy = warm / "model.zip"
    if not policy.is_file():
        raise TrainingError(f"warm start {warm} holds no model.zip: train that job first")
    model = cls.load(policy, env=env, device="cpu")
    model.set_random_seed(seed)
    buffers = [b for _, b, _ in checkpoints(warm / "checkpoints") if b is not None]
    if buffers and isinstance(model, OffPolicyAlgorithm):
        model.load_replay_buffer(buffers[0])
    model.num_timesteps = 0
    return model


def keep_best_policy(
    model: BaseAlgorithm,
    evaluation: ResumableEvalCallback,
    training: TrainingSpec,
    env: DummyVecEnv,
) -> tuple[BaseAlgorithm, int | None]:
    """The policy to keep after a budget ran out: the best evaluation's when it beat the last
    one (a policy that was good once and then unlearned), else ``model``."""
    last, best, path = evaluation.last_success_rate, evaluation.best, evaluation.best_path
    if best is None or last is None or best[1] <= last or path is None or not path.is_file():
        return model, None
    return ALGORITHMS[training.algorithm].load(path, env=env, device="cpu"), best[0]


def _checkpoint(model: BaseAlgorithm, folder: Path, steps: int) -> None:
    """Save model (and replay buffer) as the checkpoint of ``steps``, as CheckpointCallback."""
    folder.mkdir(parents=True, exist_ok=True)
    model.save(folder / f"model_{steps}_steps.zip")
    if isinstance(model, OffPolicyAlgorithm):
        model.save_replay_buffer(folder / f"model_replay_buffer_{steps}_steps.pkl")
