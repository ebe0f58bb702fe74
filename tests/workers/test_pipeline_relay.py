"""The local pipeline's relay: what the jobs put on the progress queue reaches the driver's
callbacks, progress and the evaluations a job runs once its training has ended."""

from __future__ import annotations

import queue
import threading
from typing import Any

from workers.pipeline import _QueueProgress, _relay


def test_progress_and_evaluations_reach_their_callbacks() -> None:
    updates: queue.Queue[Any] = queue.Queue()
    hooks = _QueueProgress(subtask=2, updates=updates, offset=1000, driver=0)
    hooks.progress(500, 0.5, 2000)
    hooks.evaluating("final evaluation: 200 trials")
    hooks.put(500, 0.5, 2000, True)
    done = threading.Event()
    done.set()
    shown: list[tuple[Any, ...]] = []
    said: list[tuple[Any, ...]] = []
    _relay(updates, done, lambda *a: shown.append(a), lambda *a: said.append(a))
    assert shown == [(2, 1500, 0.5, 3000, False), (2, 1500, 0.5, 3000, True)]
    assert said == [(2, "final evaluation: 200 trials")]
    hooks.evaluating("picking the kept policy: 1 of 2")
    _relay(updates, done, lambda *a: shown.append(a), None)  # nobody asked: dropped
    assert updates.empty() and len(said) == 1
