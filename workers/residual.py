"""Residual training: an agent that starts as the env's feed-forward and is measured as such.

With ``EnvOptions.guide_feedforward`` the env adds a command along the guide to the policy's
action, so the zero action already drives (``envs.feedforward``). A fresh agent's output layer
starts at zero, so its deterministic policy is exactly that controller, as residual policy
learning starts from its base controller (Silver et al. 2018; Johannink et al. 2019).
``train_subtask`` measures that starting policy before the first update (:func:`start_check`):
when it already meets the target the job stops at step 0 and says so, so training never
unlearns a controller that works (measured on the racecar: SAC took the U-turn sub-tasks from
80-100 % at the start down to 0 % for 10-20k steps before it recovered).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from stable_baselines3.common.base_class import BaseAlgorithm

from workers.atomic import write_json
from workers.evaluation import SubtaskEvaluation
from workers.policy_act import is_jax_policy

START_RECORD = "start_check.json"
"""File in a job's folder that keeps the start check's quick evaluation across restarts."""


def zero_output_layer(model: BaseAlgorithm) -> None:
    """Set the weights and bias of the layer that outputs the action mean to zero (SAC, TD3
    and DDPG actors, PPO's action net, SBX's SAC actor; a target actor is synced)."""
    if is_jax_policy(model.policy):
        from workers.sbx_agent import SbxSAC, zero_mean_head  # loaded: the model is one

        assert isinstance(model, SbxSAC)
        zero_mean_head(model)
        return
    policy = model.policy
    actor = getattr(policy, "actor", None)
    head = actor.mu if actor is not None else getattr(policy, "action_net", None)
    if not isinstance(head, torch.nn.Module):
        raise TypeError(f"no action head found on {type(policy).__name__}")
    last = [m for m in head.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    target = getattr(policy, "actor_target", None)
    if actor is not None and target is not None:
        target.load_state_dict(actor.state_dict())


@dataclass(frozen=True)
class StartCheck:
    """The starting policy's success rate over a periodic evaluation, and the final
    evaluation that confirmed the target (None: it did not, or was not asked)."""

    success_rate: float
    confirmed: SubtaskEvaluation | None


def start_check(
    quick: Callable[[], SubtaskEvaluation],
    confirm: Callable[[], SubtaskEvaluation],
    target: float,
    folder: Path,
) -> StartCheck:
    """``quick()`` (a periodic evaluation's episodes), then ``confirm()`` (the final
    evaluation's) if the quick one reaches ``target``; the rate is kept in ``folder``."""
    first = quick()
    write_json(folder / START_RECORD, first.to_json())
    rate = first.success_rate
    if rate < target:
        return StartCheck(rate, None)
    full = confirm()
    return StartCheck(rate, full if full.success_rate >= target else None)


def recorded_start(folder: Path) -> SubtaskEvaluation | None:
    """The quick evaluation of the start check of the job in ``folder`` (None: none was made);
    the step-0 point of its learning curve."""
    path = folder / START_RECORD
    return SubtaskEvaluation(**json.loads(path.read_text())) if path.is_file() else None
