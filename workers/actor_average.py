"""An exponential average of an off-policy agent's actor weights, the policy its evaluations
measure and the job keeps (weight averaging against the instability of deep RL's policies:
Nikishin et al. 2018, "Improving Stability in Deep Reinforcement Learning with Weight
Averaging").

The learner goes on updating its own actor; the average follows it with a time constant of
``horizon`` env steps, updated after every gradient round. ``in_place()`` puts the average into
the actor for an evaluation, ``commit()`` for good once training ends.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import torch
from stable_baselines3.common.callbacks import BaseCallback


class AveragedActor(BaseCallback):
    """The average of ``model.actor``'s weights over about the last ``horizon`` env steps.

    Started from the actor's weights when training starts (or resumes: the average is not
    checkpointed); after ``s`` more env steps it moves ``1 - exp(-s / horizon)`` of the way to
    the actor's current weights.
    """

    def __init__(self, horizon: int) -> None:
        super().__init__()
        if horizon < 1:
            raise ValueError(f"the average's horizon must be at least 1 env step, not {horizon}")
        self.horizon = horizon
        self.average: list[torch.Tensor] = []
        self._updated_at = 0

    def _weights(self) -> list[torch.Tensor]:
        actor = getattr(self.model, "actor", None)
        if not isinstance(actor, torch.nn.Module):
            raise TypeError(f"{type(self.model).__name__} has no torch actor to average")
        return [p.data for p in actor.parameters()]

    def _on_training_start(self) -> None:
        self.average = [w.clone() for w in self._weights()]
        self._updated_at = self.num_timesteps

    def _on_rollout_start(self) -> None:
        """Follow the actor as the last gradient round (after the last rollout) left it."""
        steps = self.num_timesteps - self._updated_at
        if steps <= 0 or not self.average:
            return
        fraction = -math.expm1(-steps / self.horizon)
        torch._foreach_lerp_(self.average, self._weights(), fraction)
        self._updated_at = self.num_timesteps

    def _on_step(self) -> bool:
        return True

    @contextmanager
    def in_place(self) -> Iterator[None]:
        """The average in the actor for the block's duration (its own weights after)."""
        if not self.average:
            yield
            return
        weights = self._weights()
        own = [w.clone() for w in weights]
        torch._foreach_copy_(weights, self.average)
        try:
            yield
        finally:
            torch._foreach_copy_(weights, own)

    def commit(self) -> None:
        """Put the average into the actor for good."""
        if self.average:
            torch._foreach_copy_(self._weights(), self.average)
