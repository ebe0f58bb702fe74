"""Residual training: a fresh agent with a feed-forward starts as that controller, and a job
whose starting policy already meets the target stops at step 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import DummyVecEnv

from planner.plan import MissionPlan
from workers.agents import ALGORITHMS
from workers.hooks import CurvePoint
from workers.jobs import SubtaskJob
from workers.mission import MissionSpec
from workers.residual import recorded_start, zero_output_layer
from workers.run import stored_or_new_plan
from workers.training import TrainResult, subtask_env, train_subtask
from workers.training_spec import TrainingSpec

from .missions import Recorder, tiny_mission


@pytest.mark.parametrize("algorithm", ["sac", "td3", "ddpg", "ppo"])
def test_a_zeroed_output_layer_makes_the_zero_action(algorithm: str, tmp_path: Path) -> None:
    mission = tiny_mission()
    plan = stored_or_new_plan(mission, tmp_path)
    env = DummyVecEnv([lambda: subtask_env(mission, plan, mission.training, 0)])
    model = ALGORITHMS[algorithm](
        "MlpPolicy", env, learning_rate=1e-3, policy_kwargs={"net_arch": [8]}, seed=0
    )
    obs = np.stack([env.observation_space.sample() for _ in range(5)])
    assert np.abs(model.predict(obs, deterministic=True)[0]).max() > 0
    zero_output_layer(model)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], 0.0)
    target = getattr(model.policy, "actor_target", None)
    if target is not None:  # TD3 and DDPG bootstrap from the target actor
        np.testing.assert_array_equal(target(model.policy.obs_to_tensor(obs)[0]).detach(), 0.0)
    env.close()


def _unicycle(tmp_path: Path, gain: float) -> tuple[MissionSpec, MissionPlan, SubtaskJob]:
    mission = tiny_mission(env={"guide_feedforward": gain}, n_timesteps=200)
    document = mission.model_dump(mode="json")
    document["robot"] = {"model": "unicycle", "start": [0.5, 0.5], "radius": 0.05}
    mission = type(mission).model_validate(document)
    plan = stored_or_new_plan(mission, tmp_path / "plan")
    return mission, plan, SubtaskJob(subtask=0, training=mission.training, seed=3)


def _train(tmp_path: Path, gain: float, out: Path, hooks: Recorder | None = None) -> TrainResult:
    mission, plan, job = _unicycle(tmp_path, gain)
    return train_subtask(mission, plan, job, out, hooks)


def test_a_feedforward_that_meets_the_target_stops_the_job_at_step_0(tmp_path: Path) -> None:
    out = tmp_path / "job"
    hooks = Recorder()
    result = _train(tmp_path, 1.0, out, hooks)
    assert (result.steps, result.stopped, result.curve) == (0, "target", [(0, 1.0)])
    assert result.final is not None and result.final["success_rate"] == 1.0
    start = recorded_start(out)
    assert start is not None and (start.success_rate, start.episodes) == (1.0, 1)
    assert hooks.progressed[-1] == (0, 1.0, 200)
    assert hooks.points == [CurvePoint(0, 1, 1.0)]  # the start check is the curve's first point
    assert _train(tmp_path, 1.0, out) == result  # stored, not redone


def test_a_start_below_the_target_trains_on_and_stays_on_the_curve(tmp_path: Path) -> None:
    out = tmp_path / "job"
    result = _train(tmp_path, 0.01, out)
    assert result.curve[0][0] == 0 and result.curve[0][1] < 0.95
    assert [s for s, _ in result.curve[1:]] == [100, 200]
    assert result.steps == 200


@pytest.mark.parametrize("burn_in", [0, 150, 1000])
def test_during_the_actor_burn_in_only_the_critic_learns(tmp_path: Path, burn_in: int) -> None:
    mission, plan, job = _unicycle(tmp_path, 0.01)
    training = mission.training.model_copy(update={"actor_burn_in": burn_in})
    job = SubtaskJob(subtask=0, training=training, seed=3)
    result = train_subtask(mission, plan, job, tmp_path / "job")
    assert result.steps == 200
    model = SAC.load(result.model_path, device="cpu")
    env = subtask_env(mission, plan, training, 0)
    obs = np.stack([env.observation_space.sample() for _ in range(5)])
    actions = model.predict(obs, deterministic=True)[0]
    assert model.log_ent_coef is not None  # SAC's default: the entropy coefficient is learned
    if burn_in > 200:  # the actor never stepped: the agent is still its controller
        np.testing.assert_array_equal(actions, 0.0)
        assert model.log_ent_coef.item() == 0.0
    else:
        assert np.abs(actions).max() > 0 and model.log_ent_coef.item() != 0.0
    assert model.actor.optimizer.step.__name__ == "step"  # unfrozen once training ended


@pytest.mark.parametrize("field", ["actor_burn_in", "actor_average_steps"])
@pytest.mark.parametrize(
    ("changes", "learner"), [({"algorithm": "ppo"}, "ppo"), ({"backend": "sbx"}, "backend sbx")]
)
def test_an_option_on_the_actor_the_learner_cannot_apply_is_refused(
    field: str, changes: dict[str, str], learner: str
) -> None:
    with pytest.raises(ValueError, match=f"{field}.*not available with {learner}"):
        TrainingSpec.model_validate({field: 100, **changes})
