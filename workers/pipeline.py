"""The local pipeline behind ``ltlnav train``: a ``MissionRun`` driven with K processes.

Plan (or reuse ``plan.json``), train every sub-task in a process pool, evaluate the whole
mission, repair hand-overs while it is below its target, write ``bundle.zip``. Re-running it on
the same output folder resumes: each job resumes from its checkpoints or returns its stored
result.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.managers import SyncManager
from pathlib import Path
from typing import Any

from workers.hooks import TrainingHooks
from workers.jobs import SubtaskJob
from workers.limits import AdmissionLimits
from workers.mission import MissionSpec
from workers.run import MissionRun, RunResult, Spread
from workers.train_result import TrainResult

DRIVER_POLL_SECONDS = 1.0
"""How often the progress queue's manager and the pool workers check that the driver still
runs (``_follow_driver``)."""

PipelineProgress = Callable[[int, int, float | None, int, bool], None]
"""``on_progress(subtask, steps, success_rate, total, done)``, called in the parent process;
``done`` once the job has finished (at its budget, its target or a cancel)."""

PipelineEvaluating = Callable[[int, str], None]
"""``on_evaluating(subtask, what)``, called in the parent process when a job's training has
ended and it evaluates (``TrainingHooks.evaluating``)."""


class _QueueProgress(TrainingHooks):
    """A job's progress put on the parent's queue, its steps counted from ``offset`` (a repair
    continues the sub-task's bar); the job stops (after a checkpoint, so a re-run resumes it)
    once the process ``driver`` that waits for it is gone."""

    def __init__(self, subtask: int, updates: Any, offset: int, driver: int) -> None:
        self.subtask, self.updates, self.offset = subtask, updates, offset
        self.driver = driver

    def should_stop(self) -> bool:
        return not process_alive(self.driver)

    def progress(self, steps: int, success_rate: float | None, total: int) -> None:
        self.put(steps, success_rate, total, False)

    def evaluating(self, what: str) -> None:
        self.updates.put(("evaluating", (self.subtask, what)))

    def put(self, steps: int, success_rate: float | None, total: int, done: bool) -> None:
        offset = self.offset
        update = (self.subtask, offset + steps, success_rate, offset + total, done)
        self.updates.put(("progress", update))


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (a killed ``ltlnav train`` leaves its pool's workers
    behind: they ask this to stop instead of training on for nobody)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _run_job(
    run: MissionRun, job: SubtaskJob, updates: Any, offset: int, driver: int
) -> TrainResult:
    """One training job in a worker process."""
    hooks = _QueueProgress(job.subtask, updates, offset, driver)
    _training.set()
    try:
        result = run.train(job, hooks)
    finally:
        _training.clear()
    if not process_alive(driver):
        os._exit(0)  # nobody waits for the result, and an idle worker would wait forever
    rate = result.curve[-1][1] if result.curve else None
    hooks.put(result.steps, rate, job.training.n_timesteps, True)
    return result


_training = threading.Event()
"""Set in a pool worker while it trains a job (which stops by itself, after a checkpoint)."""


def _follow_driver(driver: int) -> None:
    """In the progress queue's manager and in every pool worker: exit once the driver is gone
    (a worker that trains, once its job has stopped). They would otherwise wait for a
    shutdown, or a task, that nobody sends, and keep the forkserver (which lives while a
    process it forked does) and the resource tracker alive: a killed ``ltlnav train`` left
    them all behind."""

    def watch() -> None:
        while process_alive(driver) or _training.is_set():
            time.sleep(DRIVER_POLL_SECONDS)
        os._exit(0)

    threading.Thread(target=watch, name="follow-driver", daemon=True).start()


def training_context() -> multiprocessing.context.ForkServerContext:
    """The process context of training pools: workers fork from a clean single-threaded server
    (a driver may run threads, as the pipeline's relay), which imports torch and
    stable-baselines3 once for all of them."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["workers.training"])
    return context


def run_pipeline(
    mission: MissionSpec,
    out_dir: str | Path,
    jobs: int | None = None,
    on_progress: PipelineProgress | None = None,
    limits: AdmissionLimits | None = None,
    on_evaluating: PipelineEvaluating | None = None,
) -> RunResult:
    """Open the run of ``mission`` in ``out_dir``, train its sub-tasks (``jobs`` processes,
    default the CPU count), roll out the concatenated policy (its lanes shared out over the
    same processes), repair hand-overs while the mission is below its target and write
    ``out_dir/bundle.zip``. The training section
    (budget, seed, ...) is the mission's own: override it on the spec before calling.
    ``limits``: see ``MissionRun.open``. ``on_evaluating``: see ``PipelineEvaluating``."""
    run = MissionRun.open(mission, out_dir, limits)
    first = run.jobs()
    if on_progress is not None:  # every sub-task shows up at once, in order
        for job in first:
            on_progress(job.subtask, 0, None, job.training.n_timesteps, False)
    workers = max(1, min(jobs or os.cpu_count() or 1, len(first)))
    driver = os.getpid()
    context = training_context()
    manager = SyncManager(ctx=context)
    manager.start(_follow_driver, (driver,))
    with manager:
        updates = manager.Queue()
        done = threading.Event()
        relay = threading.Thread(
            target=_relay, args=(updates, done, on_progress, on_evaluating), daemon=True
        )
        relay.start()
        try:
            with ProcessPoolExecutor(
                max_workers=workers,
                mp_context=context,
                initializer=_follow_driver,
                initargs=(driver,),
            ) as pool:
                steps_before: dict[int, int] = {}

                def train_all(batch: Sequence[SubtaskJob]) -> list[TrainResult]:
                    futures = [
                        pool.submit(
                            _run_job, run, job, updates, steps_before.get(job.subtask, 0), driver
                        )
                        for job in batch
                    ]
                    out = [f.result() for f in futures]
                    for job, result in zip(batch, out, strict=True):
                        steps_before[job.subtask] = steps_before.get(job.subtask, 0) + result.steps
                    return out

                run.spread = Spread(pool.map, workers)
                results = train_all(first)
                evaluation = run.evaluate(results)
                results, evaluation, repairs = run.repair(results, evaluation, train_all)
                return run.finish(results, evaluation, repairs)
        finally:
            done.set()
            relay.join()


def _relay(
    updates: Any,
    done: threading.Event,
    on_progress: PipelineProgress | None,
    on_evaluating: PipelineEvaluating | None,
) -> None:
    while True:
        try:
            item = updates.get(timeout=0.2)
        except queue.Empty:
            if done.is_set():
                return
            continue
        except (EOFError, OSError):
            return
        kind, update = item
        if kind == "progress" and on_progress is not None:
            on_progress(*update)
        elif kind == "evaluating" and on_evaluating is not None:
            on_evaluating(*update)
