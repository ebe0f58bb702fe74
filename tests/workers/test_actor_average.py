"""``training.actor_average_steps``: evaluations and the kept policy use an exponential average
of the actor's weights, computed here independently from the weights the learner went through."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.vec_env import DummyVecEnv

from workers.actor_average import AveragedActor
from workers.jobs import SubtaskJob
from workers.run import stored_or_new_plan
from workers.training import subtask_env, train_subtask

from .missions import tiny_mission


class _ActorWeights(BaseCallback):
    """The actor's weights at the start of every rollout (after the gradient round before it)."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, list[torch.Tensor]]] = []

    def _weights(self) -> list[torch.Tensor]:
        model = self.model
        assert isinstance(model, SAC)
        return [p.detach().clone() for p in model.actor.parameters()]

    def _on_training_start(self) -> None:
        self.seen.append((self.num_timesteps, self._weights()))

    def _on_rollout_start(self) -> None:
        self.seen.append((self.num_timesteps, self._weights()))

    def _on_step(self) -> bool:
        return True


def _expected_average(
    seen: list[tuple[int, list[torch.Tensor]]], horizon: int
) -> list[torch.Tensor]:
    (at, first), *rest = seen
    average = [w.double() for w in first]
    for steps, weights in rest:
        fraction = 1.0 - math.exp(-(steps - at) / horizon)
        average = [a + (w.double() - a) * fraction for a, w in zip(average, weights, strict=True)]
        at = steps
    return average


def _sac(tmp_path: Path) -> SAC:
    mission = tiny_mission()
    plan = stored_or_new_plan(mission, tmp_path)
    env = DummyVecEnv([lambda: subtask_env(mission, plan, mission.training, 0)])
    kwargs = {"net_arch": [16]}
    return SAC("MlpPolicy", env, policy_kwargs=kwargs, learning_starts=20, train_freq=2, seed=1)


@pytest.mark.parametrize("horizon", [1, 30, 10_000])
def test_the_average_follows_the_actor_with_its_time_constant(tmp_path: Path, horizon: int) -> None:
    model = _sac(tmp_path)
    recorder, averaged = _ActorWeights(), AveragedActor(horizon)
    model.learn(200, callback=CallbackList([recorder, averaged]))
    expected = _expected_average(recorder.seen, horizon)
    for got, want in zip(averaged.average, expected, strict=True):
        torch.testing.assert_close(got.double(), want, rtol=1e-5, atol=1e-6)
    own = [p.detach().clone() for p in model.actor.parameters()]
    assert any(not torch.equal(a, w) for a, w in zip(averaged.average, own, strict=True))
    with averaged.in_place():
        inside = [p.detach().clone() for p in model.actor.parameters()]
    for got, want in zip(inside, averaged.average, strict=True):
        assert torch.equal(got, want)
    for got, want in zip(model.actor.parameters(), own, strict=True):
        assert torch.equal(got.detach(), want)  # its own weights back after the block


def test_every_evaluation_and_the_kept_policy_are_the_average(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    made: list[_Counted] = []

    class _Counted(AveragedActor):
        def __init__(self, horizon: int) -> None:
            super().__init__(horizon)
            self.evaluated: dict[int, list[torch.Tensor]] = {}
            made.append(self)

        @contextmanager
        def in_place(self) -> Iterator[None]:
            self.evaluated[self.model.num_timesteps] = [a.clone() for a in self.average]
            with super().in_place():
                yield

    monkeypatch.setattr("workers.training.AveragedActor", _Counted)
    mission = tiny_mission(n_timesteps=300)
    training = mission.training.model_copy(update={"actor_average_steps": 50})
    plan = stored_or_new_plan(mission, tmp_path / "plan")
    job = SubtaskJob(subtask=0, training=training, seed=2)
    result = train_subtask(mission, plan, job, tmp_path / "job")
    (averaged,) = made
    assert result.stopped == "budget"
    assert [steps for steps, _ in result.curve] == list(averaged.evaluated) == [100, 200, 300]
    kept = list(SAC.load(result.model_path, device="cpu").actor.parameters())
    want = (
        averaged.average if result.policy_steps is None else averaged.evaluated[result.policy_steps]
    )
    for got, average in zip(kept, want, strict=True):
        assert torch.equal(got.detach(), average)
    last = SAC.load(tmp_path / "job" / "checkpoints" / "model_300_steps.zip", device="cpu")
    learned = list(last.actor.parameters())  # the learner's own actor, checkpointed for a resume
    assert any(not torch.equal(k.detach(), w.detach()) for k, w in zip(kept, learned, strict=True))
