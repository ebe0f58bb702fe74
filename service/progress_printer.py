"""What ``ltlnav submit --wait`` prints while it follows a mission: one line per change worth
reading, not one per poll."""

from __future__ import annotations

from typing import Any

import typer


class ProgressPrinter:
    """Prints a mission's status when it changes, its news (a hand-over repair round starting)
    once, and a job's progress when its status changes, it passes another tenth of its budget
    or it starts another evaluation once its training has ended: the sub-tasks' jobs, then the
    repair jobs of each round."""

    def __init__(self) -> None:
        self.shown: dict[str, Any] = {}

    def __call__(self, mission: dict[str, Any]) -> None:
        self._line("status", mission["status"], f"status: {mission['status']}")
        final = mission["status"] in ("done", "failed", "cancelled")
        news = None if final else mission.get("reason")
        if news:
            self._line("news", news.partition(":")[0], f"  {news}")
        for job in mission.get("jobs", []):
            self._job(job, f"sub-task {job['index']}")
        for job in mission.get("repairs", []):
            self._job(job, f"repair {job['round']} of sub-task {job['index']}")

    def _job(self, job: dict[str, Any], name: str) -> None:
        rate = job.get("success_rate")
        eta, reason = job.get("eta_seconds"), job.get("reason")
        running = job["status"] == "running"
        evaluating = reason if running and eta is None else None
        text = (
            f"  {name}: {job['status']}, {job['steps_done']}/{job['budget']}"
            f" steps, success {'-' if rate is None else f'{100 * rate:.0f} %'}"
            + ("" if eta is None or not running else f", ETA {eta:.0f} s")
            + (f", {evaluating}" if evaluating else "")
        )
        tenth = 10 * job["steps_done"] // max(job["budget"], 1)
        self._line(f"{name}", (job["status"], tenth, evaluating), text)

    def _line(self, key: str, value: Any, text: str) -> None:
        if self.shown.get(key) != value:
            self.shown[key] = value
            typer.echo(text)
