"""The stable-baselines3 hyperparameters a mission may set, per algorithm, under their RL-Zoo
names, and the checks of ``policy_kwargs`` (``workers.training_spec.TrainingSpec``)."""

from __future__ import annotations

import importlib.util
from typing import Any

_OFF_POLICY = frozenset(
    {
        "learning_rate",
        "buffer_size",
        "learning_starts",
        "batch_size",
        "tau",
        "gamma",
        "train_freq",
        "gradient_steps",
        "optimize_memory_usage",
        "policy_kwargs",
        "noise_type",
        "noise_std",
    }
)
HYPERPARAMETERS: dict[str, frozenset[str]] = {
    "sac": _OFF_POLICY
    | {
        "ent_coef",
        "target_update_interval",
        "target_entropy",
        "use_sde",
        "sde_sample_freq",
        "use_sde_at_warmup",
    },
    "td3": _OFF_POLICY | {"policy_delay", "target_policy_noise", "target_noise_clip"},
    "ddpg": _OFF_POLICY,
    "ppo": frozenset(
        {
            "learning_rate",
            "n_steps",
            "batch_size",
            "n_epochs",
            "gamma",
            "gae_lambda",
            "clip_range",
            "clip_range_vf",
            "normalize_advantage",
            "ent_coef",
            "vf_coef",
            "max_grad_norm",
            "use_sde",
            "sde_sample_freq",
            "target_kl",
            "policy_kwargs",
        }
    ),
}
"""Valid hyperparameter names per algorithm (RL-Zoo spelling; ``noise_type``/``noise_std``
build the off-policy action noise, ``normal`` or ``ornstein-uhlenbeck``)."""

POLICY_KWARGS = frozenset(
    {"net_arch", "activation_fn", "log_std_init", "n_critics", "share_features_extractor"}
)
"""Valid keys of ``hyperparams.policy_kwargs``; ``activation_fn`` is a name (``ACTIVATIONS``)."""

ACTIVATIONS = ("relu", "tanh", "elu", "leaky_relu", "gelu", "silu")
"""Activation names accepted for ``policy_kwargs.activation_fn`` (``torch.nn`` modules)."""

DEFAULT_POLICY_KWARGS: dict[str, Any] = {"net_arch": [64, 64, 64], "activation_fn": "relu"}
"""Actor and critic MLP [64, 64, 64] with ReLU, as in Cai et al.; keys given in
``hyperparams.policy_kwargs`` override these one by one. Every other hyperparameter not given
takes stable-baselines3's default for the algorithm, except for the off-policy ones
``buffer_size``: ``n_timesteps``, since a larger buffer never fills and every checkpoint stores
it whole, and ``train_freq``: 2 (``OFF_POLICY_TRAIN_FREQ``)."""

OFF_POLICY_TRAIN_FREQ = 2
"""Env steps between gradient steps of the off-policy agents unless ``hyperparams.train_freq``
is given (SB3's default: 1): half the updates per env step. Measured side by side with the
default before it (``bench/train_speed.py``, the car mission, 3 seeds, with evaluation lanes):
wall time to the bundle 144 / 172 / 366 s against 526 / 574 / 780 s, every sub-task at the
target in as many env steps or fewer, missions 99 / 100 / 100 % against 100 / 100 / 100 %."""


def policy_kwargs_problems(value: Any) -> list[tuple[str, str]]:
    """(field, problem) of each thing wrong with ``hyperparams.policy_kwargs``."""
    where = "policy_kwargs"
    if not isinstance(value, dict):
        return [(where, "must be a mapping (e.g. {net_arch: [64, 64]})")]
    problems = [
        (f"{where}.{k}", f"unknown key; valid: {', '.join(sorted(POLICY_KWARGS))}")
        for k in value
        if k not in POLICY_KWARGS
    ]
    arch = value.get("net_arch")
    if arch is not None and not valid_arch(arch):
        problems.append(
            (f"{where}.net_arch", "must be a list of positive integers or {pi: [...], qf: [...]}")
        )
    act = value.get("activation_fn")
    if act is not None and act not in ACTIVATIONS:
        problems.append((f"{where}.activation_fn", f"must be one of {', '.join(ACTIVATIONS)}"))
    return problems


def valid_arch(arch: Any) -> bool:
    """A list of positive layer widths, or one such list per network (``pi``, ``qf``, ``vf``)."""

    def layers(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in v
        )

    if isinstance(arch, dict):
        return bool(arch) and set(arch) <= {"pi", "qf", "vf"} and all(map(layers, arch.values()))
    return layers(arch)


SBX_HYPERPARAMETERS = HYPERPARAMETERS["sac"] - {
    "optimize_memory_usage",
    "target_update_interval",
    "use_sde",
    "sde_sample_freq",
    "use_sde_at_warmup",
}
"""The SAC hyperparameters SBX's SAC takes as stable-baselines3's does (``backend: sbx``)."""

SBX_POLICY_KWARGS = frozenset({"net_arch", "activation_fn", "n_critics"})
"""The ``policy_kwargs`` keys SBX's SAC policy takes as stable-baselines3's does."""


def backend_problems(
    backend: str, algorithm: str, hyperparams: dict[str, Any]
) -> list[tuple[str, str]]:
    """(field, problem) of each thing ``backend`` cannot train as asked."""
    if backend == "sb3":
        return []
    if algorithm != "sac":
        return [("backend", f"sbx trains sac only, not {algorithm}; use backend sb3")]
    if importlib.util.find_spec("sbx") is None:
        return [("backend", "sbx is not installed: pip install -e '.[sbx]' (SBX and JAX)")]
    problems = [
        (f"hyperparams.{k}", "not supported by backend sbx; use backend sb3 for it")
        for k in hyperparams
        if k not in SBX_HYPERPARAMETERS
    ]
    kwargs = hyperparams.get("policy_kwargs")
    if isinstance(kwargs, dict):
        problems += [
            (f"hyperparams.policy_kwargs.{k}", "not supported by backend sbx; use backend sb3")
            for k in kwargs
            if k not in SBX_POLICY_KWARGS
        ]
    return problems


def actor_option_problems(
    options: dict[str, int | None], backend: str, algorithm: str
) -> list[tuple[str, str]]:
    """(field, problem) of each option on the actor of sb3's off-policy agents (field: value,
    e.g. ``actor_burn_in``) that is set (not 0 or None) for a learner without such an actor."""
    if backend == "sb3" and algorithm != "ppo":
        return []
    learner = "backend sbx" if backend != "sb3" else algorithm
    use = "use sb3's sac, td3 or ddpg, or leave it unset"
    return [(field, f"not available with {learner}; {use}") for field, v in options.items() if v]


def env_count_problems(
    n_envs: int,
    algorithm: str,
    hyperparams: dict[str, Any],
    counts: dict[str, int | None],
) -> list[tuple[str, str]]:
    """(field, problem) of each thing that ``n_envs`` envs per learner cannot honour: the step
    counts (``counts``, by field name) and an off-policy ``train_freq``, which SB3 counts in
    steps of all the envs at once, must be multiples of ``n_envs``. A ``train_freq`` of no
    form SB3 takes is a problem whatever ``n_envs``."""
    problems = [
        (field, f"{value} is not a multiple of n_envs ({n_envs}), whose envs step together")
        for field, value in counts.items()
        if value is not None and value % n_envs
    ]
    if algorithm == "ppo":
        return problems
    freq = hyperparams.get("train_freq", OFF_POLICY_TRAIN_FREQ)
    if isinstance(freq, int) and not isinstance(freq, bool):
        steps, unit = freq, "step"
    elif isinstance(freq, list | tuple) and len(freq) == 2 and isinstance(freq[0], int):
        steps, unit = freq
    else:
        unit = "form"
    if unit not in ("step", "episode") or steps < 1:
        shape = "a positive number of env steps, or [n, 'step' or 'episode'] with n positive"
        return [*problems, ("hyperparams.train_freq", shape)]
    if n_envs == 1:
        return problems
    if unit != "step":
        problems.append(
            ("hyperparams.train_freq", f"counts {unit}s, which SB3 trains with one env only")
        )
    elif steps % n_envs:
        problems.append(
            (
                "hyperparams.train_freq",
                f"{steps} env steps between updates is not a multiple of n_envs ({n_envs}): "
                "set train_freq to one",
            )
        )
    return problems
