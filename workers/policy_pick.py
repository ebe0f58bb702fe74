"""Which policy a job keeps when its budget ran out or it stopped on a plateau, with
``training.pick_candidates``: the policies of its best periodic evaluations
(``workers.candidates``) and its last one, each evaluated on the same seeds of their own.

A periodic evaluation of 50 episodes that made 92 % may be a policy of 81 % (the racecar's
controller on seed 15's forest, ``bench/LEARNING.md``): the first best of them keeps what luck
ranked first. Every candidate here runs the same ``episodes`` from the same seed (common
starts, so the comparison is of the policies), the best periodic one first; each later one
stops once it can no longer beat the best so far. The one with most successes is kept, the
earlier on a tie.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TypeVar

from workers.candidates import Candidate
from workers.evaluation import SubtaskEvaluation

Model = TypeVar("Model")

Trial = tuple[int, float, int]
"""``(steps, success rate, episodes)`` of one candidate's evaluation in the pick; one that
stopped once it could no longer win has its rate over the episodes it ran."""


def pick_policy(
    last: Model,
    last_steps: int,
    candidates: Sequence[Candidate],
    load: Callable[[Path], Model],
    evaluate: Callable[[Model, int], SubtaskEvaluation],
    announce: Callable[[int, int], None] = lambda number, of: None,
) -> tuple[Model, int | None, list[Trial]]:
    """The policy to keep of ``candidates`` (best first) and ``last`` (the policy at
    ``last_steps``), ``evaluate(policy, needed)`` deciding (it may stop once ``needed``
    successes are out of reach): the kept one, its steps (None: ``last``) and every trial.
    ``announce(number, of)`` is called before the ``number``-th of ``of`` policies runs."""
    entries: list[tuple[int, Callable[[], Model]]] = [
        (c.steps, partial(load, c.path)) for c in candidates if c.steps != last_steps
    ]
    entries.append((last_steps, lambda: last))
    kept, kept_steps, most = last, last_steps, -1
    trials: list[Trial] = []
    for number, (steps, policy) in enumerate(entries, start=1):
        announce(number, len(entries))
        model = policy()
        check = evaluate(model, most + 1)
        trials.append((steps, check.success_rate, check.episodes))
        successes = round(check.success_rate * check.episodes)
        if successes > most:
            kept, kept_steps, most = model, steps, successes
    return kept, None if kept_steps == last_steps else kept_steps, trials


def kept_policy_text(policy_steps: int | None, selection: Sequence[Trial]) -> str:
    """``policy of step 130000, the pick's best of 4: 90.5 % of 200 trials``: the policy a job
    kept when not its last, and how ('' for the last)."""
    if policy_steps is None:
        return ""
    trial = next((t for t in selection if t[0] == policy_steps), None)
    if trial is None:
        return f"policy of step {policy_steps}, its best evaluation"
    rate, episodes = 100 * trial[1], trial[2]
    how = f"the pick's best of {len(selection)}: {rate:.1f} % of {episodes} trials"
    return f"policy of step {policy_steps}, {how}"
