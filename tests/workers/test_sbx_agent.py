"""``training.backend: sbx``: SBX's SAC trains for real and every file it writes is an ordinary
stable-baselines3 archive holding the same networks, so checkpoints, resume, the kept policy and
bundles work as with SB3."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import DummyVecEnv

from envs.mission_env import MissionEnv
from planner.plan import MissionPlan
from workers.agents import algorithm_class, hyperparameters
from workers.bundle import ConcatenatedPolicy, write_bundle
from workers.evaluation import rollout_mission, stage_policies
from workers.jobs import SubtaskJob
from workers.mission import MissionError, MissionSpec
from workers.policy_act import deterministic_act
from workers.residual import zero_output_layer
from workers.sbx_agent import CRITICS, SbxSAC
from workers.training import subtask_env, train_subtask
from workers.training_spec import TrainingSpec

from .missions import Recorder, tiny_mission


def sbx_mission(**training: Any) -> MissionSpec:
    return tiny_mission(backend="sbx", **training)


def sbx_agent(mission: MissionSpec, plan: MissionPlan) -> tuple[SbxSAC, DummyVecEnv]:
    env = DummyVecEnv([lambda: subtask_env(mission, plan, mission.training, 0)])
    cls = algorithm_class(mission.training)
    assert cls is SbxSAC
    shape = env.action_space.shape
    assert shape is not None
    params = hyperparameters(mission.training, int(np.prod(shape)))
    return SbxSAC("MlpPolicy", env, seed=0, device="cpu", **params), env


def probes(env: DummyVecEnv, n: int = 6) -> np.ndarray:
    shape = env.observation_space.shape
    assert shape is not None
    return np.random.default_rng(0).uniform(-1, 1, (n, *shape)).astype(np.float32)


def critic_values(model: SbxSAC, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    state = model.policy.qf_state
    return np.asarray(state.apply_fn(state.params, obs, actions))[:, :, 0]


def global_numpy_key() -> np.ndarray:
    """A copy of the key of numpy's global generator (SB3's replay buffer samples from it)."""
    return np.array(np.random.get_state(legacy=False)["state"]["key"])


def test_an_archive_holds_the_agents_networks_for_sb3(plan: MissionPlan, tmp_path: Path) -> None:
    mission = sbx_mission()
    model, env = sbx_agent(mission, plan)
    model.learn(120)  # 50 steps to learn from, then updates: the weights moved from their init
    path = tmp_path / "model.zip"
    sampled_by_the_buffer = global_numpy_key()
    model.save(path)
    assert np.array_equal(global_numpy_key(), sampled_by_the_buffer)  # not reseeded
    archived = SAC.load(path, device="cpu")
    assert archived.num_timesteps == model.num_timesteps == 120 and archived.seed == 0
    obs = probes(env)
    actions = model.predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(archived.predict(obs, deterministic=True)[0], actions, atol=1e-5)
    with torch.no_grad():
        q = archived.critic(torch.as_tensor(obs), torch.as_tensor(actions))
    expected = critic_values(model, obs, actions)
    np.testing.assert_allclose(np.stack([v.numpy()[:, 0] for v in q]), expected, atol=1e-5)
    assert archived.log_ent_coef is not None
    log_coef = float(model.ent_coef_state.params["log_ent_coef"])
    assert float(archived.log_ent_coef.detach()) == pytest.approx(log_coef, abs=1e-6)
    assert log_coef != 0.0  # the coefficient learned: the archive did not keep the initial 1
    assert archived.batch_size == 16 and archived.buffer_size == 5000
    env.close()


def test_an_agent_loads_from_its_archive_as_it_was(plan: MissionPlan, tmp_path: Path) -> None:
    mission = sbx_mission()
    model, env = sbx_agent(mission, plan)
    model.learn(120)
    model.save(tmp_path / "model.zip")
    loaded = SbxSAC.load(tmp_path / "model.zip", env=env)
    obs = probes(env)
    actions = model.predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], actions, atol=1e-6)
    np.testing.assert_allclose(
        critic_values(loaded, obs, actions), critic_values(model, obs, actions), atol=1e-6
    )
    targets = [m.policy.qf_state.target_params["params"][CRITICS] for m in (loaded, model)]
    for a, b in zip(*(t.values() for t in targets), strict=True):
        np.testing.assert_allclose(np.asarray(a["kernel"]), np.asarray(b["kernel"]), atol=1e-7)
    assert loaded.num_timesteps == 120 and loaded.batch_size == 16
    assert loaded.train_freq == model.train_freq and loaded.buffer_size == 5000
    loaded.learn(30, reset_num_timesteps=False)  # and trains on
    assert loaded.num_timesteps == 150
    env.close()


def test_a_zeroed_mean_layer_makes_the_zero_action(plan: MissionPlan) -> None:
    model, env = sbx_agent(sbx_mission(), plan)
    obs = probes(env)
    assert np.abs(model.predict(obs, deterministic=True)[0]).max() > 0
    zero_output_layer(model)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], 0.0)
    np.testing.assert_array_equal(deterministic_act(model.policy)(obs), 0.0)
    head = model.policy.actor_state.params["params"]["Dense_1"]  # net_arch [8]: the mean layer
    assert not jnp.any(head["kernel"]) and not jnp.any(head["bias"])
    env.close()


def test_a_job_checkpoints_resumes_warm_starts_and_keeps_sb3_archives(
    plan: MissionPlan, tmp_path: Path
) -> None:
    mission = sbx_mission()
    out = tmp_path / "job"
    job = SubtaskJob(subtask=0, training=mission.training, seed=3)
    first = train_subtask(mission, plan, job, out)
    assert (first.steps, first.stopped) == (200, "budget") and first.final is not None
    assert [s for s, _ in first.curve] == [100, 200]
    assert SAC.load(out / "checkpoints" / "model_200_steps.zip").num_timesteps == 200
    assert SAC.load(first.model_path).num_timesteps == 200
    more = TrainingSpec.model_validate({**mission.training.model_dump(), "n_timesteps": 300})
    hooks = Recorder()
    second = train_subtask(mission, plan, SubtaskJob(subtask=0, training=more, seed=3), out, hooks)
    assert hooks.resumes == [200] and (second.resumed_from, second.steps) == (200, 300)
    assert [s for s, _ in second.curve] == [100, 200, 300]
    short = TrainingSpec.model_validate({**mission.training.model_dump(), "n_timesteps": 100})
    repair = dataclasses.replace(job, training=short, warm_start=out, seed=9, round=1)
    warm = train_subtask(mission, plan, repair, out / "handover_1")
    assert (warm.steps, warm.resumed_from) == (100, 0)
    model = SAC.load(warm.model_path, device="cpu")
    model.load_replay_buffer(
        out / "handover_1" / "checkpoints" / "model_replay_buffer_100_steps.pkl"
    )
    assert model.replay_buffer is not None and model.replay_buffer.size() == 300 + 100


def test_a_mission_trained_with_sbx_runs_from_its_bundle(plan: MissionPlan, tmp_path: Path) -> None:
    mission = sbx_mission(n_timesteps=60, eval_freq=60, final_eval_episodes=1)
    jobs = [
        SubtaskJob(subtask=k, training=mission.training, seed=k) for k in range(len(plan.subtasks))
    ]
    results = [train_subtask(mission, plan, j, tmp_path / str(j.subtask)) for j in jobs]
    models = [SAC.load(r.model_path, device="cpu") for r in results]  # a bundle's readers
    policy_acts = [deterministic_act(m.policy) for m in models]
    options = mission.training.eval_env_options(mission.robot.model)
    env = MissionEnv(mission, plan, options, cycles=1)
    evaluation = rollout_mission(stage_policies(env.sequence, policy_acts), env, episodes=1)
    env.close()
    seeds = list(range(len(plan.subtasks)))
    bundle = write_bundle(tmp_path / "bundle.zip", mission, plan, results, evaluation, seeds)
    concatenated = ConcatenatedPolicy.load(bundle)
    probe_env = concatenated.make_env()
    obs, _ = probe_env.reset(seed=0)
    concatenated.reset(obs)
    for stage in range(len(probe_env.sequence)):
        probe = obs.copy()
        probe[-1] = stage
        k = concatenated.subtask_of(stage)
        expected = models[k].predict(probe[:-1], deterministic=True)[0]
        np.testing.assert_allclose(concatenated.act(probe), expected, atol=1e-5)
    probe_env.close()
    concatenated.close()


def test_what_sbx_cannot_train_is_refused_naming_the_field() -> None:
    with pytest.raises(MissionError, match=r"training\.backend: sbx trains sac only, not td3"):
        tiny_mission(backend="sbx", algorithm="td3", hyperparams={})
    with pytest.raises(MissionError, match=r"training\.hyperparams\.use_sde: not supported"):
        tiny_mission(backend="sbx", hyperparams={"use_sde": True})
    with pytest.raises(MissionError, match=r"policy_kwargs\.log_std_init: not supported"):
        tiny_mission(backend="sbx", hyperparams={"policy_kwargs": {"log_std_init": -2}})
    with pytest.raises(MissionError, match=r"training\.backend"):
        tiny_mission(backend="jax")
