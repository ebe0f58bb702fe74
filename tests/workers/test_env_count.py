"""``training.n_envs``: several copies of the training env per learner, the same gradient steps
per env step, evaluations and checkpoints at the same env steps, and resumes that keep the
count."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer

from planner.plan import MissionPlan
from workers.agents import TrainingError, hyperparameters
from workers.jobs import SubtaskJob
from workers.mission import MissionError, MissionSpec
from workers.training import train_subtask
from workers.training_spec import TrainingSpec

from .missions import TINY, Recorder, tiny_mission


def job(mission: MissionSpec, **training: Any) -> SubtaskJob:
    spec = TrainingSpec.model_validate({**mission.training.model_dump(), **training})
    return SubtaskJob(subtask=0, training=spec, seed=3)


def updates(path: str) -> int:
    return int(SAC.load(path, device="cpu")._n_updates)


@pytest.mark.parametrize("backend", ["sb3", "sbx"])
def test_two_envs_update_as_often_per_env_step_and_evaluate_and_save_at_the_same_steps(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, backend: str
) -> None:
    one = train_subtask(mission, plan, job(mission, backend=backend), tmp_path / "one")
    hooks = Recorder()
    two_envs = job(mission, n_envs=2, backend=backend)
    two = train_subtask(mission, plan, two_envs, tmp_path / "two", hooks)
    assert (two.steps, two.stopped) == (one.steps, one.stopped) == (200, "budget")
    assert [s for s, _ in two.curve] == [s for s, _ in one.curve] == [100, 200]
    assert [s for s, _ in hooks.saved] == [100, 200, 200]
    assert abs(updates(two.model_path) - updates(one.model_path)) <= 1
    buffer = tmp_path / "two" / "checkpoints" / "model_replay_buffer_200_steps.pkl"
    model = SAC.load(two.model_path, device="cpu")
    model.load_replay_buffer(buffer)
    assert isinstance(model.replay_buffer, ReplayBuffer) and model.replay_buffer.n_envs == 2

    longer = job(mission, n_envs=2, backend=backend, n_timesteps=300)
    more = train_subtask(mission, plan, longer, tmp_path / "two")
    assert (more.resumed_from, more.steps) == (200, 300)
    with pytest.raises(TrainingError, match=r"2 env\(s\) per learner .* set n_envs back to 2"):
        train_subtask(mission, plan, job(mission, n_timesteps=400), tmp_path / "two")


def test_the_counts_that_envs_step_together_through_must_be_multiples_of_them() -> None:
    with pytest.raises(MissionError) as caught:
        tiny_mission(n_envs=3)
    message = str(caught.value)
    assert "training.eval_freq: 100 is not a multiple of n_envs (3)" in message
    assert "training.hyperparams.train_freq: 2 env steps between updates" in message
    episodic = {**TINY["training"]["hyperparams"], "train_freq": [1, "episode"]}
    with pytest.raises(MissionError, match=r"train_freq: counts episodes"):
        tiny_mission(n_envs=2, hyperparams=episodic)
    with pytest.raises(MissionError, match=r"checkpoint_freq: 25 is not a multiple"):
        tiny_mission(n_envs=2, checkpoint_freq=25)
    for malformed in (5.5, "2", [3], [0, "step"], [1, "epoch"], -1):  # whatever n_envs
        with pytest.raises(MissionError, match=r"train_freq: a positive number of env steps"):
            tiny_mission(hyperparams={"train_freq": malformed})
    four = tiny_mission(n_envs=4, hyperparams={"train_freq": 8})
    assert hyperparameters(four.training, 2)["train_freq"] == 2
    assert hyperparameters(tiny_mission(n_envs=2).training, 2)["train_freq"] == 1
    ppo = tiny_mission(n_envs=3, algorithm="ppo", eval_freq=99, hyperparams={})
    assert ppo.training.n_envs == 3  # n_steps counts each env's steps
