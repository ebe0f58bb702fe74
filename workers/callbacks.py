"""Training callbacks of a sub-task job: evaluation that survives restarts, early stop on the
success rate, checkpoints the driver is told of, cooperative cancel and throttled progress.

Each class does one job, in the style of ``stable_baselines3.common.callbacks``; what the
driver hears goes through ``workers.hooks.TrainingHooks``.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from workers.actor_average import AveragedActor
from workers.atomic import save_with, write_json
from workers.candidates import CandidateStore
from workers.checkpoints import prune_checkpoints, save_checkpoint
from workers.evaluation import SubtaskEvaluation
from workers.hooks import CurvePoint, TrainingHooks
from workers.stopwatch import Stopwatch


class ResumableEvalCallback(EvalCallback):
    """``EvalCallback`` whose ``evaluations.npz`` history continues across restarts and which
    keeps the policy of its best evaluation (by success rate) at ``best_path``.

    ``restore(upto)`` reloads the history the previous run wrote (entries after step ``upto``,
    the checkpoint the run resumes from, are dropped: those steps are redone). Every new
    evaluation is told to ``hooks.curve_point``. With ``averaged``, every evaluation (and the
    kept policy) is that of the actor's average.
    """

    def __init__(
        self,
        *args: Any,
        best_path: Path | None = None,
        start_rate: float | None = None,
        hooks: TrainingHooks | None = None,
        averaged: AveragedActor | None = None,
        stopwatch: Stopwatch | None = None,
        candidates: CandidateStore | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.history: Path | None = None
        """The evaluations file (``evaluations.npz`` in ``log_path``); SB3 writes each new
        version beside it (``.partial``), renamed over it once this attempt may write."""
        if self.log_path is not None:
            self.history = Path(self.log_path + ".npz")
            self.log_path = self.log_path + ".partial"
        self.fenced = False
        self.best_path = best_path
        """Where the policy of the best evaluation so far is kept (None: not kept)."""
        self.best: tuple[int, float] | None = None
        """``(steps, success rate)`` of the kept policy: the first evaluation with the highest
        success rate."""
        self.start_rate = start_rate
        """Success rate of the policy before any update (``workers.residual``'s start check):
        the curve's step-0 point. None: not measured."""
        self.hooks = hooks or TrainingHooks()
        self.averaged = averaged
        self.stopwatch = stopwatch or Stopwatch()
        self.candidates = candidates
        """Where the policies of the best evaluations are kept for the pick (None: not)."""

    def _on_step(self) -> bool:
        if not (self.eval_freq > 0 and self.n_calls % self.eval_freq == 0):
            return True  # no evaluation due: SB3's EvalCallback does nothing either
        with self._evaluated_actor(), self.stopwatch.part("periodic evaluations"):
            evaluations = len(self.evaluations_successes)
            go_on = super()._on_step()
            rate = self.last_success_rate
            if len(self.evaluations_successes) > evaluations:
                assert rate is not None
                if not self._keep_history():
                    return False
                steps = int(self.num_timesteps)
                returns = np.asarray(self.evaluations_results[-1], dtype=float)
                mean_return = float(np.mean(returns)) if returns.size else None
                self.hooks.curve_point(CurvePoint(steps, int(returns.size), rate, mean_return))
                self.offer(self.model, steps, rate)
        return go_on

    def _evaluated_actor(self) -> AbstractContextManager[None]:
        """The actor's average in place for an evaluation (with ``averaged``)."""
        return self.averaged.in_place() if self.averaged is not None else nullcontext()

    def _keep_history(self) -> bool:
        """Rename SB3's new evaluations file over the history if this attempt may still write
        (else drop it, set ``fenced`` and return False: training stops)."""
        if self.history is None or self.log_path is None:
            return True
        partial = Path(self.log_path + ".npz")
        if not self.hooks.may_write():
            partial.unlink(missing_ok=True)
            self.fenced = True
            return False
        if partial.is_file():
            os.replace(partial, self.history)
        return True

    def offer(self, model: BaseAlgorithm, steps: int, rate: float) -> None:
        """Keep ``model`` (evaluated at ``rate`` after ``steps``) if it beats the kept one, and
        among the candidates if it is one of the best."""
        candidates = self.candidates
        if candidates is not None and not candidates.wanted(steps, rate):
            candidates = None
        best_path = self.best_path
        if best_path is not None and self.best is not None and rate <= self.best[1]:
            best_path = None
        if candidates is None and best_path is None:
            return
        if not self.hooks.may_write():
            self.fenced = True
            return
        if candidates is not None:
            candidates.add(steps, rate, model.save)
        if best_path is None:
            return
        self.best = (steps, rate)
        save_with(best_path, model.save)
        write_json(best_path.with_suffix(".json"), {"steps": steps, "success_rate": rate})

    def restore(self, upto: int) -> None:
        """Load the earlier evaluations of ``log_path`` up to step ``upto`` (if any), and the
        kept best policy and candidates if they are not from a later step."""
        if self.candidates is not None:
            self.candidates.restore(upto)
        if self.best_path is not None:
            record = self.best_path.with_suffix(".json")
            if record.is_file() and self.best_path.is_file():
                doc = json.loads(record.read_text())
                if int(doc["steps"]) <= upto:
                    self.best = (int(doc["steps"]), float(doc["success_rate"]))
        path = self.history
        if path is None or not path.is_file():
            return
        with np.load(path) as data:
            steps = data["timesteps"].tolist()
            keep = [k for k, t in enumerate(steps) if t <= upto]
            self.evaluations_timesteps = [int(steps[k]) for k in keep]
            self.evaluations_results = [data["results"][k].tolist() for k in keep]
            self.evaluations_length = [data["ep_lengths"][k].tolist() for k in keep]
            if "successes" in data:
                self.evaluations_successes = [[bool(v) for v in data["successes"][k]] for k in keep]

    @property
    def success_curve(self) -> list[tuple[int, float]]:
        """``(steps, success rate)`` of every evaluation so far, the start check's first."""
        start = [(0, self.start_rate)] if self.start_rate is not None else []
        return start + [
            (int(t), float(np.mean(s)))
            for t, s in zip(self.evaluations_timesteps, self.evaluations_successes, strict=False)
        ]

    @property
    def last_success_rate(self) -> float | None:
        """The success rate of the latest evaluation (before the first: the start check's, or
        None)."""
        if not self.evaluations_successes:
            return self.start_rate
        return float(np.mean(self.evaluations_successes[-1]))


class StopOnSuccessRate(BaseCallback):
    """Stop training once the parent evaluation's success rate reaches ``target``
    (``callback_after_eval`` of a ``ResumableEvalCallback``).

    With ``confirm`` (a larger evaluation of the current policy, e.g. the final one), a periodic
    rate at the target only stops training when ``confirm()`` reaches it too: a 50-episode
    evaluation at 96 % measured 93 % over 200 episodes. ``confirmed`` keeps the evaluation that
    stopped training, ``confirmations`` every ``(steps, success rate)`` asked for.
    """

    def __init__(
        self, target: float, confirm: Callable[[], SubtaskEvaluation] | None = None
    ) -> None:
        super().__init__()
        self.target = target
        self.confirm = confirm
        self.reached = False
        self.confirmed: SubtaskEvaluation | None = None
        self.confirmations: list[tuple[int, float]] = []

    def _on_step(self) -> bool:
        parent = self.parent
        assert isinstance(parent, ResumableEvalCallback)
        rate = parent.last_success_rate
        self.reached = rate is not None and rate >= self.target
        if self.reached and self.confirm is not None:
            check = self.confirm()
            self.confirmations.append((int(self.num_timesteps), check.success_rate))
            self.logger.record("eval/confirmed_success_rate", check.success_rate)
            self.reached = check.success_rate >= self.target
            self.confirmed = check if self.reached else None
        return not self.reached


def evaluations_since_best(curve: Sequence[tuple[int, float]]) -> int:
    """Evaluations of ``curve`` (``(steps, success rate)``) after its first highest success
    rate, the one whose policy ``ResumableEvalCallback`` keeps (0: none, or the last is it)."""
    rates = [rate for _, rate in curve]
    return len(rates) - 1 - rates.index(max(rates)) if rates else 0


class StopOnPlateau(BaseCallback):
    """Stop training once ``plateaued(evaluation.success_curve, patience, floor, episodes)``
    (the start check's rate, when measured, is the curve's first point); ``patience`` None:
    never."""

    def __init__(
        self,
        evaluation: ResumableEvalCallback,
        patience: int | None,
        floor: float,
        episodes: int,
    ) -> None:
        super().__init__()
        self.evaluation = evaluation
        self.patience, self.floor, self.episodes = patience, floor, episodes
        self.plateaued = False
        self._seen = len(evaluation.evaluations_successes)

    def _on_step(self) -> bool:
        evaluations = len(self.evaluation.evaluations_successes)
        if self.patience is None or evaluations == self._seen:
            return True
        self._seen = evaluations
        curve = self.evaluation.success_curve
        self.plateaued = plateaued(curve, self.patience, self.floor, self.episodes)
        return not self.plateaued


def plateaued(
    curve: Sequence[tuple[int, float]], patience: int | None, floor: float, episodes: int
) -> bool:
    """Whether ``curve`` (evaluations of ``episodes`` episodes each) is flat near its best: the
    best success rate is at least ``floor``, the last ``patience`` evaluations did not beat it,
    and their median is at least ``plateau_level(floor, episodes)``, so that a policy that fell
    after its best (SAC's collapses) trains on (``patience`` None: never)."""
    if patience is None or not curve or evaluations_since_best(curve) < patience:
        return False
    recent = [rate for _, rate in curve[-patience:]]
    level = plateau_level(floor, episodes)
    return max(rate for _, rate in curve) >= floor and statistics.median(recent) >= level


def plateau_level(floor: float, episodes: int) -> float:
    """``floor`` less two standard errors of an evaluation of ``episodes`` episodes of a policy
    whose success rate is ``floor``: its evaluations' median stays above this."""
    return floor - 2 * math.sqrt(floor * (1 - floor) / max(episodes, 1))


class StopOnRequest(BaseCallback):
    """Stop training when ``should_stop()`` says so; asked at most every ``interval`` seconds
    (it may query a database) and on the first step."""

    def __init__(self, should_stop: Callable[[], bool], interval: float = 0.5) -> None:
        super().__init__()
        self.should_stop = should_stop
        self.interval = interval
        self.stopped = False
        self._last = -np.inf

    def _on_step(self) -> bool:
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self.stopped = bool(self.should_stop())
        return not self.stopped


class ReportProgress(BaseCallback):
    """Call ``on_progress(steps, success_rate, total)`` at most every ``interval`` seconds and
    after every evaluation."""

    def __init__(
        self,
        on_progress: Callable[[int, float | None, int], None],
        total: int,
        evaluation: ResumableEvalCallback,
        interval: float = 1.0,
    ) -> None:
        super().__init__()
        self.on_progress = on_progress
        self.total = total
        self.evaluation = evaluation
        self.interval = interval
        self._last = -np.inf
        self._evals = 0

    def _on_step(self) -> bool:
        now = time.monotonic()
        evals = len(self.evaluation.evaluations_successes)
        if now - self._last >= self.interval or evals != self._evals:
            self._last, self._evals = now, evals
            self.report()
        return True

    def report(self) -> None:
        """Report the current state now."""
        self.on_progress(self.num_timesteps, self.evaluation.last_success_rate, self.total)


class ReportedCheckpoints(BaseCallback):
    """A checkpoint (model and replay buffer, ``workers.checkpoints``) every ``every`` steps,
    told to ``hooks.checkpoint``; when ``hooks.may_write()`` says the job is no longer this
    attempt's, training stops instead and ``fenced`` is set."""

    def __init__(
        self, every: int, folder: Path, hooks: TrainingHooks, stopwatch: Stopwatch | None = None
    ) -> None:
        super().__init__()
        self.every, self.folder, self.hooks = every, folder, hooks
        self.stopwatch = stopwatch or Stopwatch()
        self.fenced = False

    def _on_step(self) -> bool:
        if self.n_calls % self.every != 0:
            return True
        if not self.hooks.may_write():
            self.fenced = True
            return False
        steps = int(self.num_timesteps)
        with self.stopwatch.part("checkpoints"):
            self.hooks.checkpoint(steps, save_checkpoint(self.model, self.folder, steps))
        return True


class ActorBurnIn(BaseCallback):
    """Until ``steps`` env steps, the off-policy agent's gradient steps update its critic only:
    the actor's optimizer (and SAC's entropy coefficient's) takes no step, so a residual agent
    drives as its controller while its critic learns the value of that behaviour (the burn-in of
    residual policy learning, Silver et al. 2018). Switched at the end of each rollout, before
    the ``train`` call that follows it."""

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.steps = steps

    def _frozen_optimizers(self) -> list[torch.optim.Optimizer]:
        actor = getattr(self.model, "actor", None)
        found = [getattr(actor, "optimizer", None), getattr(self.model, "ent_coef_optimizer", None)]
        return [o for o in found if isinstance(o, torch.optim.Optimizer)]

    def _switch(self, frozen: bool) -> None:
        for optimizer in self._frozen_optimizers():
            if frozen:
                optimizer.step = _no_step  # type: ignore[method-assign, assignment]
            else:
                optimizer.__dict__.pop("step", None)

    def _on_rollout_end(self) -> None:
        self._switch(self.num_timesteps < self.steps)

    def _on_training_end(self) -> None:
        self._switch(False)

    def _on_step(self) -> bool:
        return True


def _no_step(*_args: Any, **_kwargs: Any) -> None:
    """An optimizer step that changes nothing (``ActorBurnIn``)."""


class PruneCheckpoints(BaseCallback):
    """Keep only the newest checkpoints, checked every ``every`` steps."""

    def __init__(self, folder: Path, every: int, keep: int = 2) -> None:
        super().__init__()
        self.folder, self.every, self.keep = folder, every, keep

    def _on_step(self) -> bool:
        if self.n_calls % self.every == 0:
            prune_checkpoints(self.folder, self.keep)
        return True
