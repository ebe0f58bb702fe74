"""SAC on JAX (SBX, ``training.backend: sbx``) that reads and writes stable-baselines3 archives.

SBX is stable-baselines3's API on JAX: the same algorithm, callbacks and replay buffers, with the
update compiled by XLA (``bench/learner_backends.py`` measures its rate beside SB3's). Its own
archives pickle JAX state, while everything else here (checkpoints, the best and the final
policy, warm starts, bundles, rollouts) reads SB3 archives. ``SbxSAC`` therefore saves as an
SB3 ``SAC`` archive holding the same weights (actor, every critic and its target, the entropy
coefficient) and loads from one: the files a job writes are the same whichever backend trained
it. Adam's moment estimates are not carried across: an agent resumed from a checkpoint or
warm-started keeps its weights, entropy coefficient and replay buffer, and its optimiser state
starts afresh.

Import this module through ``workers.agents.algorithm_class``, which keeps JAX to the CPU.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax.numpy as jnp
import numpy as np
import sbx
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.type_aliases import TrainFreq

Params = dict[str, Any]

FLAX_ACTIVATIONS: dict[str, Callable[[jnp.ndarray], jnp.ndarray]] = {
    "ReLU": nn.relu,
    "Tanh": nn.tanh,
    "ELU": nn.elu,
    "LeakyReLU": nn.leaky_relu,
    "GELU": functools.partial(nn.gelu, approximate=False),  # torch's GELU is the exact one
    "SiLU": nn.silu,
}
"""The flax function of each ``torch.nn`` activation module a policy may name."""

CRITICS = "VmapContinuousCritic_0"
"""SBX's name for the vectorised critics (one leading axis: the critic's index)."""


class SbxSAC(sbx.SAC):
    """SBX's SAC built from the same keywords as stable-baselines3's (``policy_kwargs`` with a
    ``torch.nn`` activation class), saved to and loaded from SB3 ``SAC`` archives."""

    def __init__(self, policy: str, env: Any, **kwargs: Any) -> None:
        kwargs.pop("device", None)  # JAX runs on the CPU (workers.agents.algorithm_class)
        torch_kwargs = dict(kwargs.pop("policy_kwargs", None) or {})
        jax_kwargs = dict(torch_kwargs)
        if "activation_fn" in torch_kwargs:
            jax_kwargs["activation_fn"] = FLAX_ACTIVATIONS[torch_kwargs["activation_fn"].__name__]
        super().__init__(policy, env, policy_kwargs=jax_kwargs, **kwargs)
        self._sb3_kwargs = {**kwargs, "policy_kwargs": torch_kwargs}
        self._twin: SAC | None = None

    def save(self, path: Any, exclude: Any = None, include: Any = None) -> None:
        """Write an SB3 ``SAC`` archive of this agent's weights and counters."""
        self.sb3_twin().save(path, exclude, include)

    @classmethod
    def load(  # type: ignore[override]
        cls, path: str | Path, env: Any = None, device: str = "cpu", **_: Any
    ) -> SbxSAC:
        """The agent in an SB3 ``SAC`` archive, with the archive's hyperparameters."""
        archived = SAC.load(path, env=env, device="cpu")
        model = cls("MlpPolicy", env, **archived_keywords(archived))
        set_weights(model, archived.policy.state_dict(), log_ent_coef(archived))
        model.num_timesteps = archived.num_timesteps
        model._n_updates = archived._n_updates
        return model

    def sb3_twin(self) -> SAC:
        """An SB3 ``SAC`` holding this agent's current weights (built once, then updated)."""
        if self._twin is None:
            # a one-transition buffer: the twin never collects, its archive keeps the real size;
            # no seed: SB3 would reseed the process's global generators with it mid-training
            keywords = {**self._sb3_kwargs, "buffer_size": 1, "learning_starts": 0, "seed": None}
            assert self.env is not None, "an agent saves with its env"
            twin = SAC("MlpPolicy", self.env, device="cpu", **keywords)
            twin.buffer_size, twin.learning_starts = self.buffer_size, self.learning_starts
            twin.seed = self.seed
            self._twin = twin
        twin = self._twin
        twin.policy.load_state_dict(sb3_state_dict(self))
        if isinstance(self.ent_coef_init, str) and twin.log_ent_coef is not None:
            value = float(self.ent_coef_state.params["log_ent_coef"])
            with torch.no_grad():
                twin.log_ent_coef.fill_(value)
        twin.num_timesteps = self.num_timesteps
        twin._n_updates = self._n_updates
        twin._episode_num = self._episode_num
        return twin


def archived_keywords(archived: SAC) -> dict[str, Any]:
    """The constructor keywords of an SB3 ``SAC`` as restored from its archive."""
    freq = archived.train_freq
    assert isinstance(freq, TrainFreq), "a loaded agent's train_freq is converted"
    return {
        "learning_rate": archived.learning_rate,
        "buffer_size": archived.buffer_size,
        "learning_starts": archived.learning_starts,
        "batch_size": archived.batch_size,
        "tau": archived.tau,
        "gamma": archived.gamma,
        "train_freq": (freq.frequency, freq.unit.value),
        "gradient_steps": archived.gradient_steps,
        "ent_coef": archived.ent_coef,
        "target_entropy": float(archived.target_entropy),
        "action_noise": archived.action_noise,
        "policy_kwargs": archived.policy_kwargs,
        "seed": archived.seed,
    }


def log_ent_coef(archived: SAC) -> float | None:
    """The learned log entropy coefficient of an SB3 ``SAC`` (None: a fixed coefficient)."""
    value = getattr(archived, "log_ent_coef", None)
    return None if value is None else float(value.detach().reshape(()))


def sb3_state_dict(model: SbxSAC) -> dict[str, torch.Tensor]:
    """The weights of ``model`` as SB3's ``SACPolicy.state_dict()`` names them."""
    policy = model.policy
    state = _dense_layers(policy.actor_state.params["params"], "actor", len(policy.net_arch_pi))
    for name, params in (
        ("critic", policy.qf_state.params),
        ("critic_target", policy.qf_state.target_params),
    ):
        layers = params["params"][CRITICS]
        for k in range(policy.n_critics):
            single = {layer: {p: v[k] for p, v in w.items()} for layer, w in layers.items()}
            for i in range(len(single)):
                state.update(_linear(single[f"Dense_{i}"], f"{name}.qf{k}.{2 * i}"))
    return state


def _dense_layers(params: Params, prefix: str, hidden: int) -> dict[str, torch.Tensor]:
    state: dict[str, torch.Tensor] = {}
    for i in range(hidden):
        state.update(_linear(params[f"Dense_{i}"], f"{prefix}.latent_pi.{2 * i}"))
    state.update(_linear(params[f"Dense_{hidden}"], f"{prefix}.mu"))
    state.update(_linear(params[f"Dense_{hidden + 1}"], f"{prefix}.log_std"))
    return state


def _linear(dense: Params, name: str) -> dict[str, torch.Tensor]:
    """A flax ``Dense`` (kernel in x out) as a ``torch.nn.Linear`` (weight out x in)."""
    kernel = np.asarray(dense["kernel"], dtype=np.float32)
    bias = np.asarray(dense["bias"], dtype=np.float32)
    weight = torch.from_numpy(kernel.T.copy())
    return {f"{name}.weight": weight, f"{name}.bias": torch.from_numpy(bias.copy())}


def set_weights(
    model: SbxSAC, state: dict[str, torch.Tensor], log_coef: float | None = None
) -> None:
    """Put SB3 ``SACPolicy`` weights (``state``) and the log entropy coefficient into
    ``model``; its optimiser states are left as they are."""
    policy = model.policy
    hidden = len(policy.net_arch_pi)
    names = [f"latent_pi.{2 * i}" for i in range(hidden)] + ["mu", "log_std"]
    actor = {f"Dense_{i}": _dense(state, f"actor.{n}") for i, n in enumerate(names)}
    policy.actor_state = policy.actor_state.replace(params={"params": actor})

    def critics(prefix: str) -> Params:
        depth = len(policy.net_arch_qf) + 1
        layers = {}
        for i in range(depth):
            each = [_dense(state, f"{prefix}.qf{k}.{2 * i}") for k in range(policy.n_critics)]
            layers[f"Dense_{i}"] = {p: jnp.stack([d[p] for d in each]) for p in ("kernel", "bias")}
        return {"params": {CRITICS: layers}}

    policy.qf_state = policy.qf_state.replace(
        params=critics("critic"), target_params=critics("critic_target")
    )
    if log_coef is not None and isinstance(model.ent_coef_init, str):
        model.ent_coef_state = model.ent_coef_state.replace(
            params={"log_ent_coef": jnp.asarray(log_coef, dtype=jnp.float32)}
        )


def _dense(state: dict[str, torch.Tensor], name: str) -> dict[str, jnp.ndarray]:
    weight = state[f"{name}.weight"].detach().cpu().numpy()
    return {"kernel": jnp.asarray(weight.T), "bias": jnp.asarray(state[f"{name}.bias"].numpy())}


def zero_mean_head(model: SbxSAC) -> None:
    """Set the weights and bias of the actor's mean layer to zero (``workers.residual``)."""
    policy = model.policy
    params = {k: dict(v) for k, v in policy.actor_state.params["params"].items()}
    head = f"Dense_{len(policy.net_arch_pi)}"
    params[head] = {p: jnp.zeros_like(v) for p, v in params[head].items()}
    policy.actor_state = policy.actor_state.replace(params={"params": params})
