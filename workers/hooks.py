"""What a training job tells its driver while it runs, and what it asks it.

``train_subtask`` calls these hooks; the local pipeline relays progress to its progress bars,
the service stores what it is told in the database (it reads no file the job writes). Every
hook has a do-nothing default, so a driver overrides only what it uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class CurvePoint:
    """One point of a job's learning curve: an evaluation after ``steps`` env steps (step 0:
    the start check of a residual agent, ``workers.residual``)."""

    steps: int
    episodes: int
    success_rate: float
    mean_return: float | None = None


class TrainingHooks:
    """The hooks of one training job (all optional; subclass and override)."""

    def resumed(self, steps: int) -> None:
        """Training (re)starts at ``steps``: curve points after it will be made again."""

    def progress(self, steps: int, success_rate: float | None, total: int) -> None:
        """About once a second and after every evaluation: env steps done (restored ones
        included), the latest periodic evaluation's success rate (None before the first) and
        the budget."""

    def curve_point(self, point: CurvePoint) -> None:
        """A new point of the learning curve."""

    def evaluating(self, what: str) -> None:
        """Training has ended and the job evaluates before it returns; ``what`` says which
        evaluation (``picking the kept policy: 2 of 4``, ``final evaluation: 200 trials``).
        No step is trained after it, so no time is left to estimate from steps."""

    def checkpoint(self, steps: int, path: Path) -> None:
        """A checkpoint (model and replay buffer) was saved at ``path`` after ``steps``."""

    def should_stop(self) -> bool:
        """Asked about twice a second: True stops the job after a checkpoint (cancelled)."""
        return False

    def may_write(self) -> bool:
        """Asked right before the job writes a file into its folder (a checkpoint, its best
        policy, its result): False means another attempt owns the job now, and this one stops
        without writing (its result is ``cancelled``)."""
        return True
