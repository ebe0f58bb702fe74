"""One training job of a mission run: which sub-task, with which training section and seed,
from which starts, beginning from which finished policy.

A job is a small typed value: the mission and its plan travel with the run that owns it
(``workers.run.MissionRun``), never inside the job. ``to_json``/``from_json`` exist for the
one place a job must be stored, the service's job row of a hand-over repair.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.geometry.pose import Pose
from workers.training_spec import TrainingSpec


def job_seed(training: TrainingSpec, subtask: int) -> int:
    """The seed of sub-task ``subtask``'s own training job (round 0)."""
    return training.seed + subtask


@dataclass(frozen=True)
class SubtaskJob:
    """Train sub-task ``subtask`` with ``training`` and ``seed``.

    ``round`` 0 is the sub-task's own training; round ``r > 0`` is its ``r``-th hand-over
    repair (``workers.handover_repair``): it starts from ``starts`` (the poses mission rollouts
    handed the sub-task over in) and from the finished job in ``warm_start``.
    """

    subtask: int
    training: TrainingSpec
    seed: int
    round: int = 0
    starts: tuple[Pose, ...] | None = None
    """Start poses of training and evaluation episodes in place of the real starts (None:
    the sub-task's hand-over poses from the plan, ``envs.handover``)."""
    warm_start: Path | None = None
    """Folder of a finished job of this sub-task: begin from its policy and newest replay
    buffer when this job's own folder holds no checkpoint yet."""

    def folder(self, mission_dir: Path) -> Path:
        """Where the job writes: ``subtask_<k>/`` (round 0) or ``subtask_<k>/handover_<r>/``."""
        base = mission_dir / f"subtask_{self.subtask}"
        return base if self.round == 0 else base / f"handover_{self.round}"

    def to_json(self) -> dict[str, Any]:
        starts = None
        if self.starts is not None:
            starts = [[[float(v) for v in p.position], float(p.heading)] for p in self.starts]
        return {
            "subtask": self.subtask,
            "training": self.training.model_dump(mode="json"),
            "seed": self.seed,
            "round": self.round,
            "starts": starts,
            "warm_start": None if self.warm_start is None else str(self.warm_start),
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> SubtaskJob:
        starts = doc.get("starts")
        warm = doc.get("warm_start")
        return cls(
            subtask=int(doc["subtask"]),
            training=TrainingSpec.model_validate(doc["training"]),
            seed=int(doc["seed"]),
            round=int(doc.get("round", 0)),
            starts=None
            if starts is None
            else tuple(Pose(np.asarray(p, dtype=float), float(h)) for p, h in starts),
            warm_start=None if warm is None else Path(warm),
        )
