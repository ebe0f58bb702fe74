"""The lean SB3 learner (``workers.lean_learner``): the same weights as stable-baselines3's own
loop, bit for bit, and untouched where a mode switch could change what a network computes."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from stable_baselines3 import SAC

import workers.agents
from planner.plan import MissionPlan
from workers.jobs import SubtaskJob
from workers.lean_learner import make_lean, mode_free
from workers.mission import MissionSpec
from workers.training import train_subtask
from workers.training_spec import TrainingSpec


def trained(mission: MissionSpec, plan: MissionPlan, folder: Path) -> SAC:
    spec = TrainingSpec.model_validate({**mission.training.model_dump(), "n_timesteps": 400})
    result = train_subtask(mission, plan, SubtaskJob(subtask=0, training=spec, seed=5), folder)
    return SAC.load(result.model_path, device="cpu")


def test_a_lean_job_trains_the_same_weights_as_sb3s_own_loop(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lean = trained(mission, plan, tmp_path / "lean")
    monkeypatch.setattr(workers.agents, "make_lean", lambda model: model)
    plain = trained(mission, plan, tmp_path / "plain")
    assert lean._n_updates == plain._n_updates > 0
    weights, reference = lean.policy.state_dict(), plain.policy.state_dict()
    assert weights.keys() == reference.keys()
    assert all(torch.equal(weights[k], reference[k]) for k in weights)
    moments = lean.actor.optimizer.state_dict()["state"]
    expected = plain.actor.optimizer.state_dict()["state"]
    assert all(torch.equal(moments[i]["exp_avg_sq"], expected[i]["exp_avg_sq"]) for i in expected)
    assert lean.actor.optimizer.param_groups[0]["foreach"] is True  # what made it lean


def test_a_policy_whose_output_depends_on_its_mode_keeps_its_switches() -> None:
    assert mode_free(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.ReLU()))
    assert not mode_free(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.Dropout(0.5)))
    model = SAC("MlpPolicy", "Pendulum-v1", device="cpu", policy_kwargs={"net_arch": [8]})
    model.policy.actor.latent_pi.append(torch.nn.Dropout(0.5))
    make_lean(model)
    model.policy.set_training_mode(False)
    assert not model.policy.actor.latent_pi[-1].training  # switched, as SB3 does
