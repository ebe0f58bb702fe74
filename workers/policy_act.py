"""Deterministic actions of a stable-baselines3 policy, as ``predict`` gives them, at a fraction
of its cost per call.

Every evaluation step asks the policy for one batch of actions. ``BasePolicy.predict`` switches
every module to evaluation mode on each call (a walk over the module tree that sets an attribute
on every module) and, for SAC, builds a squashed Gaussian distribution only to take its mode,
``tanh`` of the actor's mean: on the 12-goal quadrotor's whole-mission rollouts those two were
most of the policy's cost. ``deterministic_act`` switches the policy once (again only if training
switched it back) and, for SAC without gSDE, takes ``tanh`` of the mean directly; other policies
go through their own ``_predict``; SBX's (JAX) policies through ``predict``, which compiles its
own. The actions are the same numbers (tests compare them).
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.sac.policies import Actor as SacActor

from workers.evaluation import Act


def deterministic_act(policy: BasePolicy) -> Act:
    """``policy``'s deterministic action for one observation or a batch of them (one row
    each), equal to ``policy.predict(obs, deterministic=True)[0]``."""
    space, action_space = policy.observation_space, policy.action_space
    if is_jax_policy(policy):
        return lambda obs: policy.predict(obs, deterministic=True)[0]
    if not isinstance(space, spaces.Box) or not isinstance(action_space, spaces.Box):
        return lambda obs: policy.predict(obs, deterministic=True)[0]
    obs_shape, action_shape = space.shape, action_space.shape
    actor = getattr(policy, "actor", None)
    sac_mean = actor if isinstance(actor, SacActor) and not actor.use_sde else None

    def act(obs: np.ndarray) -> np.ndarray:
        if policy.training:
            policy.set_training_mode(False)
        batch = np.asarray(obs)
        batched = batch.ndim == len(obs_shape) + 1
        tensor = torch.as_tensor(batch.reshape((-1, *obs_shape)), device=policy.device)
        with torch.no_grad():
            if sac_mean is not None:
                features = sac_mean.extract_features(tensor, sac_mean.features_extractor)
                actions = torch.tanh(sac_mean.mu(sac_mean.latent_pi(features)))
            else:
                actions = policy._predict(tensor, deterministic=True)
        out = actions.cpu().numpy().reshape((-1, *action_shape))
        if policy.squash_output:
            out = policy.unscale_action(out)
        else:
            out = np.clip(out, action_space.low, action_space.high)
        return out if batched else out.squeeze(axis=0)

    return act


def is_jax_policy(policy: BasePolicy) -> bool:
    """Whether ``policy`` is an SBX (JAX) policy, whose networks are not torch modules."""
    return hasattr(policy, "actor_state")
