"""What ``ltlnav train`` shows: a progress bar per sub-task, with its latest success rate, the
time left while it trains, the evaluation it runs once its training has ended, and the time it
took once it is done (a job that stopped at its target long before its budget shows how long
it ran, not the hours its budget would take); then the lines of the result
(``result_lines``)."""

from __future__ import annotations

from datetime import timedelta
from types import TracebackType
from typing import TYPE_CHECKING

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TaskID,
    TextColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from workers.policy_pick import kept_policy_text
from workers.stopwatch import largest_first

if TYPE_CHECKING:
    from workers.run import RunResult
    from workers.train_result import TrainResult


class RemainingOrElapsed(ProgressColumn):
    """The estimated time left while a job trains, the evaluation it runs once its training
    has ended (the ``doing`` field), the time it ran once it is done (the ``took`` field,
    seconds)."""

    def __init__(self) -> None:
        super().__init__()
        self.remaining = TimeRemainingColumn()

    def render(self, task: Task) -> Text:
        took, doing = task.fields.get("took"), task.fields.get("doing")
        if took is None and doing:
            return Text(doing, style="progress.remaining")
        if took is None:
            return self.remaining.render(task)
        return Text(f"done in {timedelta(seconds=round(took))}", style="progress.elapsed")


class TrainProgress:
    """``show(subtask, steps, success_rate, total, done)`` for ``workers.pipeline``'s
    ``on_progress`` and ``evaluating(subtask, what)`` for its ``on_evaluating``, drawn as rich
    progress bars while the block runs."""

    def __init__(self) -> None:
        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("success {task.fields[success]}"),
            RemainingOrElapsed(),
            transient=False,
        )
        self.tasks: dict[int, TaskID] = {}

    def __enter__(self) -> TrainProgress:
        self.progress.__enter__()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.progress.__exit__(kind, error, trace)

    def show(self, subtask: int, steps: int, rate: float | None, total: int, done: bool) -> None:
        task = self.tasks.get(subtask)
        if task is None:
            task = self.tasks[subtask] = self.progress.add_task(
                f"sub-task {subtask}", total=total, success="-", took=None, doing=None
            )
        shown = "-" if rate is None else f"{100 * rate:.0f} %"
        current = self.progress.tasks[task]
        took = current.elapsed if done else None
        still = steps == current.completed and current.fields.get("took") is None
        doing = current.fields.get("doing") if still else None
        self.progress.update(
            task, completed=steps, total=total, success=shown, took=took, doing=doing
        )

    def evaluating(self, subtask: int, what: str) -> None:
        task = self.tasks.get(subtask)
        if task is not None:
            self.progress.update(task, doing=what)


def time_split(seconds: float, parts: dict[str, float]) -> str:
    """`` in 948 s (learner and the rest 625, periodic evaluations 246, ...)``: a job's wall
    time and its parts, largest first ('' for a result that recorded none)."""
    return f" in {seconds:.0f} s ({largest_first(parts)})" if parts else ""


def how_stopped(result: TrainResult) -> str:
    """``budget; policy of step 130000, its best evaluation``: why a job's training ended and
    the policy it kept when not its last."""
    kept = kept_policy_text(result.policy_steps, result.selection)
    return f"{result.stopped}; {kept}" if kept else result.stopped


def result_lines(result: RunResult) -> list[str]:
    """What ``ltlnav train`` prints once a run ends: each sub-task, each hand-over repair
    round, the mission's evaluation and the bundle."""
    lines = []
    for r in result.results:
        final = r.final or {}
        rate = final.get("success_rate")
        shown = "-" if rate is None else f"{100 * rate:.1f} %"
        lines.append(
            f"  sub-task {r.subtask}: {r.steps} steps ({how_stopped(r)}), success {shown} over "
            f"{final.get('episodes', 0)} episodes{time_split(r.seconds, r.parts)}"
        )
    for repair in result.repairs:
        subtasks = ", ".join(map(str, repair.subtasks))
        lines.append(
            f"  hand-over repair {repair.round} (sub-tasks {subtasks}): mission success "
            f"{100 * repair.success_before:.0f} % -> {100 * repair.success_after:.0f} %, "
            + ("kept" if repair.kept else "discarded")
        )
    lines.append(f"mission {result.evaluation.summary()}")
    lines.append(f"bundle written to {result.bundle}")
    return lines
