"""What a training job produced (``TrainResult``, stored as ``result.json`` in its folder, in
the service's job rows and in bundles) and the records it is made of."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

Stopped = Literal["budget", "target", "plateau", "cancelled"]
"""Why a job's training ended."""

Confirmation = tuple[int, float, int | None]
"""``(steps, success rate, episodes)`` of a confirmation of the early stop. One that can no
longer reach the target stops there: its rate is over the episodes it ran (None: recorded
before confirmations stopped early, all ``final_eval_episodes``)."""


@dataclass
class TrainResult:
    """What a training job produced."""

    subtask: int
    seed: int
    model_path: str
    """The final policy (an SB3 .zip), or the last checkpoint of a cancelled job."""
    steps: int
    """Env steps trained in total (restored ones included)."""
    resumed_from: int
    """Steps restored from a checkpoint at the start of this call (0: fresh start)."""
    stopped: Stopped
    """Why training ended: the budget, the target success rate, a plateau (``plateau_evals``
    evaluations near the best without beating it: ``workers.callbacks.plateaued``), or a
    cancel request."""
    policy_steps: int | None = None
    """Steps of the policy kept when the budget ran out (or a plateau stopped training) before
    the target: that of the best periodic evaluation (the first with the highest success rate),
    if better than the last one; None: the policy at ``steps``."""
    selection: list[tuple[int, float, int]] = field(default_factory=list)
    """With ``pick_candidates``, ``(steps, success rate, episodes)`` of every policy the pick
    evaluated (``workers.policy_pick``): the kept one is at ``policy_steps``."""
    curve: list[tuple[int, float]] = field(default_factory=list)
    """``(steps, success rate)`` of every periodic evaluation (and of the start check at step 0
    of a residual agent, ``workers.residual``)."""
    confirmations: list[Confirmation] = field(default_factory=list)
    """Every confirmation of the early stop (up to ``final_eval_episodes`` each, seeds of their
    own), failed ones included; the last one of a job stopped at the target is the one that
    passed."""
    final: dict[str, Any] | None = None
    """``SubtaskEvaluation.to_json()`` over ``final_eval_episodes`` on the report seed, measured
    once after training (None when cancelled)."""
    seconds: float = 0.0
    """Wall time of this call."""
    parts: dict[str, float] = field(default_factory=dict)
    """``seconds`` by part (``workers.stopwatch``): the evaluations, checkpoints and the rest."""
    repairs: int = 0
    """Hand-over repair rounds the policy went through (``workers.handover_repair``); then
    ``final`` is measured from the poses the mission's rollouts handed the sub-task over in."""

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["curve"] = [list(p) for p in self.curve]
        out["confirmations"] = [list(p) for p in self.confirmations]
        out["selection"] = [list(p) for p in self.selection]
        return out

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> TrainResult:
        doc = dict(doc)
        doc["curve"] = [(int(s), float(r)) for s, r in doc.get("curve", [])]
        doc["confirmations"] = [stored_confirmation(c) for c in doc.get("confirmations", [])]
        doc["selection"] = [(int(s), float(r), int(n)) for s, r, n in doc.get("selection", [])]
        return cls(**doc)


def stored_confirmation(stored: list[Any]) -> Confirmation:
    """A confirmation as ``TrainResult.to_json`` or ``CONFIRMATIONS`` stores it."""
    episodes = stored[2] if len(stored) > 2 else None
    return int(stored[0]), float(stored[1]), None if episodes is None else int(episodes)
