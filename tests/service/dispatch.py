"""A ``service.jobs.steps.Dispatch`` that records what would have been sent, for the task tests."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class Recorder:
    """Remembers every follow-up task instead of sending it."""

    def __init__(self) -> None:
        self.sent: list[tuple[Any, ...]] = []

    def training(self, mission_id: str, indices: Sequence[int]) -> None:
        self.sent.append(("training", mission_id, list(indices)))

    def train(self, mission_id: str, index: int) -> None:
        self.sent.append(("train", mission_id, index))

    def assemble(self, mission_id: str) -> None:
        self.sent.append(("assemble", mission_id))

    def plan(self, mission_id: str) -> None:
        self.sent.append(("plan", mission_id))
