"""Residual training: a fresh agent with a feed-forward starts as that controller, and a job
whose starting policy already meets the target stops at step 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from planner.serialize import plan_to_dict
from workers.pipeline import plan_for
from workers.residual import recorded_start, zero_output_layer
from workers.training import ALGORITHMS, subtask_env, train_subtask
from workers.training_spec import SubtaskJob

from .missions import tiny_mission


@pytest.mark.parametrize("algorithm", ["sac", "td3", "ddpg", "ppo"])
def test_a_zeroed_output_layer_makes_the_zero_action(algorithm: str, tmp_path: Path) -> None:
    mission = tiny_mission()
    plan = plan_for(mission, tmp_path)
    env = DummyVecEnv([lambda: subtask_env(mission, plan, mission.training, 0)])
    model = ALGORITHMS[algorithm]("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=0)
    obs = np.stack([env.observation_space.sample() for _ in range(5)])
    assert np.abs(model.predict(obs, deterministic=True)[0]).max() > 0
    zero_output_layer(model)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], 0.0)
    target = getattr(model.policy, "actor_target", None)
    if target is not None:  # TD3 and DDPG bootstrap from the target actor
        np.testing.assert_array_equal(target(model.policy.obs_to_tensor(obs)[0]).detach(), 0.0)
    env.close()


def _unicycle_job(tmp_path: Path, gain: float) -> SubtaskJob:
    mission = tiny_mission(env={"guide_feedforward": gain}, n_timesteps=200)
    document = mission.model_dump(mode="json")
    document["robot"] = {"model": "unicycle", "start": [0.5, 0.5], "radius": 0.05}
    mission = type(mission).model_validate(document)
    plan = plan_for(mission, tmp_path / "plan")
    return SubtaskJob(
        mission=mission.model_dump(mode="json"),
        plan=plan_to_dict(plan),
        subtask=0,
        training=mission.training,
        seed=3,
    )


def test_a_feedforward_that_meets_the_target_stops_the_job_at_step_0(tmp_path: Path) -> None:
    out = tmp_path / "job"
    seen: list[tuple[int, float | None, int]] = []
    result = train_subtask(_unicycle_job(tmp_path, 1.0), out, on_progress=lambda *a: seen.append(a))
    assert (result.steps, result.stopped, result.curve) == (0, "target", [(0, 1.0)])
    assert result.final is not None and result.final["success_rate"] == 1.0
    start = recorded_start(out)
    assert start is not None and (start.success_rate, start.episodes) == (1.0, 1)
    assert seen[-1] == (0, 1.0, 200)
    assert train_subtask(_unicycle_job(tmp_path, 1.0), out) == result  # stored, not redone


def test_a_start_below_the_target_trains_on_and_stays_on_the_curve(tmp_path: Path) -> None:
    out = tmp_path / "job"
    result = train_subtask(_unicycle_job(tmp_path, 0.01), out)
    assert result.curve[0][0] == 0 and result.curve[0][1] < 0.95
    assert [s for s, _ in result.curve[1:]] == [100, 200]
    assert result.steps == 200
