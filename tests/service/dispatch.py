"""A ``service.jobs.common.Dispatch`` that records what would have been sent, for the task tests."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class Recorder:
    """Remembers every follow-up task instead of sending it."""

    def __init__(self) -> None:
        self.sent: list[tuple[Any, ...]] = []

    def training(self, mission_id: str, indices: Sequence[int], repair_round: int = 0) -> None:
        entry: tuple[Any, ...] = ("training", mission_id, list(indices))
        self.sent.append((*entry, repair_round) if repair_round else entry)

    def train(
        self, mission_id: str, index: int, repair_round: int = 0, countdown: float = 0.0
    ) -> None:
        entry: tuple[Any, ...] = ("train", mission_id, index)
        entry = (*entry, repair_round) if repair_round else entry
        self.sent.append((*entry, countdown) if countdown else entry)

    def assemble(self, mission_id: str, countdown: float = 0.0) -> None:
        entry: tuple[Any, ...] = ("assemble", mission_id)
        self.sent.append((*entry, countdown) if countdown else entry)

    def plan(self, mission_id: str, countdown: float = 0.0) -> None:
        entry: tuple[Any, ...] = ("plan", mission_id)
        self.sent.append((*entry, countdown) if countdown else entry)
