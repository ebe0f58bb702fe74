"""``deterministic_act`` gives exactly ``predict``'s deterministic actions."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from workers.policy_act import deterministic_act


@pytest.mark.parametrize(
    ("cls", "kwargs"),
    [(SAC, {}), (SAC, {"use_sde": True}), (TD3, {}), (PPO, {})],
    ids=["sac", "sac-gsde", "td3", "ppo"],
)
def test_same_actions_as_predict(cls: type[BaseAlgorithm], kwargs: dict[str, Any]) -> None:
    env = gym.make("Pendulum-v1")
    model = cls("MlpPolicy", env, seed=3, device="cpu", **kwargs)
    act = deterministic_act(model.policy)
    rng = np.random.default_rng(0)
    batch = rng.uniform(-3, 3, size=(7, 3)).astype(np.float32)
    expected = model.predict(batch, deterministic=True)[0]
    np.testing.assert_array_equal(act(batch), expected)
    np.testing.assert_array_equal(act(batch[2]), model.predict(batch[2], deterministic=True)[0])
    assert act(batch[2]).shape == (1,)
    assert act(batch).shape == (7, 1)


def test_switches_the_policy_to_evaluation_mode_again_after_training() -> None:
    model = SAC("MlpPolicy", gym.make("Pendulum-v1"), seed=1, device="cpu")
    act = deterministic_act(model.policy)
    act(np.zeros(3, dtype=np.float32))
    assert not model.policy.training
    model.policy.set_training_mode(True)
    act(np.zeros(3, dtype=np.float32))
    assert not model.policy.training
