"""stable-baselines3 agents of a training job: built from the training section, restored from a
checkpoint (``workers.checkpoints``) or a finished job, and the best evaluated policy kept.
"""

from __future__ import annotations

import pickle
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv

from planner.errors import LtlnavError
from workers.callbacks import ResumableEvalCallback
from workers.checkpoints import checkpoints
from workers.hyperparameters import OFF_POLICY_TRAIN_FREQ
from workers.jax_cpu import start_jax_cpu
from workers.lean_learner import make_lean
from workers.residual import zero_output_layer
from workers.training_spec import TrainingSpec

ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"sac": SAC, "td3": TD3, "ddpg": DDPG, "ppo": PPO}
"""stable-baselines3 classes by ``training.algorithm`` name."""


def algorithm_class(training: TrainingSpec) -> type[BaseAlgorithm]:
    """The class that trains ``training``: stable-baselines3's, or with ``backend: sbx`` SBX's
    SAC behind SB3 archives (``workers.sbx_agent``), JAX on the CPU with ``torch_threads`` XLA
    threads (``workers.jax_cpu``)."""
    if training.backend == "sb3":
        return ALGORITHMS[training.algorithm]
    start_jax_cpu(training.torch_threads)
    from workers.sbx_agent import SbxSAC

    return SbxSAC


ACTIVATION_MODULES: dict[str, type[torch.nn.Module]] = {
    "relu": torch.nn.ReLU,
    "tanh": torch.nn.Tanh,
    "elu": torch.nn.ELU,
    "leaky_relu": torch.nn.LeakyReLU,
    "gelu": torch.nn.GELU,
    "silu": torch.nn.SiLU,
}


class TrainingError(LtlnavError):
    """A training job that cannot run as asked (bad sub-task index, unusable plan)."""


UNREADABLE = (
    OSError,
    EOFError,
    ValueError,
    RuntimeError,
    KeyError,
    AssertionError,
    pickle.UnpicklingError,
    zipfile.BadZipFile,
)
"""What loading a damaged checkpoint raises: a model .zip cut in half opens as a zip that holds
no ``data`` entry, which SB3 reports with an ``assert`` (AssertionError)."""


def hyperparameters(training: TrainingSpec, action_dim: int) -> dict[str, Any]:
    """The SB3 constructor keywords of ``training.hyperparams`` (RL-Zoo names mapped); an
    off-policy ``train_freq`` counts the steps of one env, SB3's those of ``n_envs`` at once."""
    params = {k: v for k, v in training.hyperparams.items() if k not in ("noise_type", "noise_std")}
    if training.algorithm != "ppo":
        if "buffer_size" not in params:
            # SB3's default (1e6) is larger than any budget here and every checkpoint pickles
            # the whole preallocated buffer: never keep more transitions than the job collects.
            params["buffer_size"] = training.n_timesteps
        params.setdefault("train_freq", OFF_POLICY_TRAIN_FREQ)
    kwargs = training.policy_kwargs()
    kwargs["activation_fn"] = ACTIVATION_MODULES[kwargs["activation_fn"]]
    params["policy_kwargs"] = kwargs
    freq = params.get("train_freq")
    if isinstance(freq, list):
        freq = params["train_freq"] = (int(freq[0]), str(freq[1]))
    if training.n_envs > 1 and freq is not None:  # a multiple of it in steps (TrainingSpec)
        params["train_freq"] = (freq if isinstance(freq, int) else freq[0]) // training.n_envs
    noise = training.hyperparams.get("noise_type")
    if noise is not None:
        std = float(training.hyperparams.get("noise_std", 0.1))
        cls = NormalActionNoise if noise == "normal" else OrnsteinUhlenbeckActionNoise
        params["action_noise"] = cls(np.zeros(action_dim), std * np.ones(action_dim))
    return params


def load_agent(
    training: TrainingSpec,
    env: DummyVecEnv,
    folder: Path,
    seed: int,
    warm: Path | None = None,
    residual: bool = False,
) -> tuple[BaseAlgorithm, int]:
    """The agent and the step it resumes from: the newest readable checkpoint in ``folder``
    with its replay buffer; else, with ``warm`` (a finished job's folder), its policy and
    newest replay buffer at step 0; else a fresh agent (``residual``: its action output starts
    at zero, ``workers.residual``). An SB3 agent is lean (``workers.lean_learner``)."""
    model, steps = _agent(training, env, folder, seed, warm, residual)
    return (make_lean(model) if training.backend == "sb3" else model), steps


def _agent(
    training: TrainingSpec,
    env: DummyVecEnv,
    folder: Path,
    seed: int,
    warm: Path | None,
    residual: bool,
) -> tuple[BaseAlgorithm, int]:
    cls = algorithm_class(training)
    found = checkpoints(folder)
    if not found and warm is not None:
        return _warm_agent(cls, env, warm, seed), 0
    for path, buffer, steps in found:
        try:
            model = cls.load(path, env=env, device="cpu")
            if buffer is not None and isinstance(model, OffPolicyAlgorithm):
                model.load_replay_buffer(buffer)
        except UNREADABLE as err:
            # a checkpoint cut short by the kill that restarted this job: use an older one
            warnings.warn(f"skipping unreadable checkpoint {path.name}: {err}", stacklevel=2)
            continue
        _check_env_count(model, env, path)
        model.num_timesteps = steps
        return model, steps
    shape = env.action_space.shape
    assert shape is not None
    params = hyperparameters(training, int(np.prod(shape)))
    model = cls("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **params)
    if residual:
        zero_output_layer(model)
    return model, 0


def _warm_agent(cls: type[BaseAlgorithm], env: DummyVecEnv, warm: Path, seed: int) -> BaseAlgorithm:
    policy = warm / "model.zip"
    if not policy.is_file():
        raise TrainingError(f"warm start {warm} holds no model.zip: train that job first")
    model = cls.load(policy, env=env, device="cpu")
    model.set_random_seed(seed)
    buffers = [b for _, b, _ in checkpoints(warm / "checkpoints") if b is not None]
    if buffers and isinstance(model, OffPolicyAlgorithm):
        model.load_replay_buffer(buffers[0])
    _check_env_count(model, env, policy)
    model.num_timesteps = 0
    return model


def _check_env_count(model: BaseAlgorithm, env: DummyVecEnv, path: Path) -> None:
    """Refuse an off-policy agent whose replay buffer holds another number of envs than
    ``env`` (its transitions are stored per env, and its ``train_freq`` counts their steps)."""
    if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
        return
    had = model.replay_buffer.n_envs
    if had != env.num_envs:
        raise TrainingError(
            f"{path} was trained with {had} env(s) per learner and training.n_envs is now "
            f"{env.num_envs}: set n_envs back to {had} or train into a new folder"
        )


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
    return algorithm_class(training).load(path, env=env, device="cpu"), best[0]
