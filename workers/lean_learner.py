"""stable-baselines3's learner without work that cannot change what it computes.

SB3 switches its policy between training and evaluation mode around every env step (module by
module, in Python) and updates each network with Adam one tensor after another. For a policy
whose every module computes the same in both modes (linear layers, activations, SB3's own
containers: no dropout, no batch norm) the switch only costs time, and Adam's ``foreach``
implementation does the same arithmetic on all of a network's tensors at once. With both, SAC
trains to bit-identical weights (``tests/workers/test_lean_learner.py``) at 1.11x SB3's own
steps per second on the racecar's forest and on the car (``bench/learner_backends.py``).
"""

from __future__ import annotations

from operator import attrgetter
from types import MethodType

import torch
from stable_baselines3.common.base_class import BaseAlgorithm

MODE_FREE_TORCH: tuple[type[torch.nn.Module], ...] = (
    torch.nn.Linear,
    torch.nn.Sequential,
    torch.nn.Flatten,
    torch.nn.Identity,
    torch.nn.ReLU,
    torch.nn.Tanh,
    torch.nn.ELU,
    torch.nn.LeakyReLU,
    torch.nn.GELU,
    torch.nn.SiLU,
)
"""torch modules whose output does not depend on their training flag."""


def mode_free(module: torch.nn.Module) -> bool:
    """Whether ``module`` and everything in it compute the same in training and evaluation
    mode: torch's ``MODE_FREE_TORCH`` and SB3's own policies, networks and extractors."""
    return all(
        type(m).__module__.startswith("stable_baselines3.") or type(m) in MODE_FREE_TORCH
        for m in module.modules()
    )


def _flag_only(policy: torch.nn.Module, mode: bool) -> None:
    policy.__dict__["training"] = mode


def make_lean(model: BaseAlgorithm) -> BaseAlgorithm:
    """``model`` (SB3, torch) set to skip its mode switches when they change nothing and to run
    Adam's ``foreach`` update; returned for chaining. Its archives differ only in that flag of
    the optimizers' parameter groups, which any torch Adam loads."""
    if mode_free(model.policy):
        model.policy.set_training_mode = MethodType(_flag_only, model.policy)  # type: ignore[method-assign]
    names, _ = model._get_torch_save_params()
    for name in names:
        optimizer = attrgetter(name)(model)
        if isinstance(optimizer, torch.optim.Adam):
            for group in optimizer.param_groups:
                group["foreach"] = True
    return model
