"""Table I of Cai et al. (RA-L 2023), measured with the production training code.

Every row trains one mission's sub-tasks with one reward method and seed through the same
functions as ``ltlnav train`` and the service (a ``workers.run.MissionRun``: its ``jobs``,
``train``, ``evaluate``, ``repair`` and ``finish``) into
``OUT/<mission>/<method>/seed<N>/``. Finished jobs are reused (``train_subtask`` returns the
stored result, an interrupted one resumes from its checkpoint), so re-running the command after
an interruption continues where it stopped and ``--report`` re-prints the table.

Methods are reward modes (``workers.training_spec.RewardSpec``): ``rrt`` (ours, the default),
``rrt-paper`` (the paper's exact reward), ``ned``, ``tl`` and ``g-rrt`` (one agent on one guide
through the whole lasso; its success is reaching the end of that guide with every automaton
transition made, i.e. the whole mission from the real start, one prefix and one suffix cycle).
Rows that train every sub-task also roll out the concatenated policy on the whole mission
(``training.mission_episodes`` rollouts, ``training.cycles`` suffix cycles).

One script a little past 400 lines: the row presets, the runner and the report print one
table and resume from one folder layout.

What the env and reward cost against raw stable-baselines3 is ``bench/overhead.py``.

Run ``.venv/bin/python bench/train.py`` (the ``table1`` preset; hours on two cores) or
``--preset NAME``, ``--rows ...`` to choose, ``--report`` to print what is on disk.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import shutil
import signal
import statistics
import sys
import zipfile
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
# Run as a script, bench/ comes first on sys.path and would shadow the packages.
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from workers.jobs import SubtaskJob  # noqa: E402
from workers.mission import MissionSpec, parse_mission  # noqa: E402
from workers.pipeline import training_context  # noqa: E402
from workers.run import MissionRun, stored_or_new_plan  # noqa: E402

METHODS = ("rrt", "rrt-paper", "ned", "tl", "g-rrt")


@dataclass(frozen=True)
class Row:
    """One line of the table: a mission trained with a method and a seed."""

    mission: str
    method: str
    seed: int
    subtasks: tuple[int, ...] | None = None
    """Sub-tasks to train (None: all of them, then the whole-mission rollouts)."""
    timesteps: int | None = None
    """Budget per sub-task (None: the mission's ``training.n_timesteps``)."""
    env: tuple[tuple[str, Any], ...] = ()
    """``training.env`` overrides (a variant of the method, named in the folder)."""
    training: tuple[tuple[str, Any], ...] = ()
    """Other ``training`` overrides (``handover_rounds``, ...; named in the folder too)."""
    fixed: tuple[tuple[str, Any], ...] = ()
    """``training`` overrides a bench holds for all its rows, not named in the folder."""

    @property
    def variant(self) -> str:
        return self.method + "".join(f"+{k}={v}" for k, v in (*self.env, *self.training))

    @property
    def folder(self) -> str:
        return f"{self.mission}/{self.variant}/seed{self.seed}"

    @staticmethod
    def parse(text: str) -> Row:
        """``mission:method:seed[:subtasks[:timesteps]]``, subtasks ``all`` or ``0+1``."""
        parts = text.split(":")
        if not 3 <= len(parts) <= 5:
            raise argparse.ArgumentTypeError(f"row {text!r}: mission:method:seed[:subs[:steps]]")
        subs = None if len(parts) < 4 or parts[3] == "all" else tuple(map(int, parts[3].split("+")))
        steps = int(parts[4]) if len(parts) == 5 else None
        if parts[1] not in METHODS:
            raise argparse.ArgumentTypeError(f"method {parts[1]!r}: one of {', '.join(METHODS)}")
        return Row(parts[0], parts[1], int(parts[2]), subs, steps)


BASELINE_BUDGET = 30_000
"""Steps per sub-task of the side-by-side rows of ``table1``, every method alike; a method that
never reaches the target runs all of it. ``g-rrt`` gets the four sub-tasks' budgets together for
its one agent."""
NO_REPAIR: tuple[tuple[str, Any], ...] = (("handover_rounds", 0),)
"""The side-by-side rows train the sub-tasks only: hand-over repair would give the methods whose
missions fail more steps than the budget."""
SIDE_BY_SIDE = ("rrt", "rrt-paper", "ned", "tl")
PRESETS: dict[str, list[Row]] = {
    "table1": [
        *[
            Row("car-phi2-fin", m, s, None, BASELINE_BUDGET, training=NO_REPAIR)
            for s in (0, 1, 2)
            for m in SIDE_BY_SIDE
        ],
        Row("car-phi2-fin", "g-rrt", 0, None, 4 * BASELINE_BUDGET, training=NO_REPAIR),
        *[Row("car-phi2-fin", "rrt", s) for s in (0, 1, 2)],
        Row("quad-phi1-inf", "rrt", 0),
        Row("racecar-phi2-fin", "rrt", 0),
    ],
    "full": [
        Row(mission, method, seed)
        for mission in ("car-phi2-fin",)
        for method in METHODS
        for seed in (0, 1, 2)
    ]
    + [Row("quad-phi1-inf", "rrt", s) for s in (0, 1, 2)]
    + [Row("racecar-phi2-fin", "rrt", s) for s in (0, 1, 2)],
}
"""``table1``: every method on every car sub-task with 3 seeds at ``BASELINE_BUDGET`` without
hand-over repair (whole-mission rollouts included), ``g-rrt`` with seed 0; then ours through the
whole pipeline (the mission's budget, repair) with 3 seeds, the quadrotor and the racecar with
seed 0. ``full``: every method on every sub-task with 3 seeds at the full budget (days of CPU
on two cores)."""


def load_mission(name: str, row: Row) -> MissionSpec:
    """The named example with the row's method, seed and budget."""
    document = yaml.safe_load((ROOT / "examples" / f"{name}.yaml").read_text())
    training = document.setdefault("training", {})
    training.update(dict(row.fixed))
    training.update(dict(row.training))
    training["seed"] = row.seed
    training.setdefault("env", {}).update(dict(row.env))
    training.setdefault("reward", {})["mode"] = row.method
    if row.timesteps is not None:
        training["n_timesteps"] = row.timesteps
    return parse_mission(document)


def row_jobs(row: Row, out: Path) -> tuple[MissionRun, list[SubtaskJob]]:
    """The row's run and its jobs. The plan is made once per mission and shared by every row
    of it (``OUT/<mission>/plan.json``, copied into the row folder): a mission that sets
    ``refine_seconds`` plans by the clock, and planning per row would give each method and seed
    its own guides.
    The run is built directly, not opened: ``g-rrt`` rows train one agent, which the service
    refuses to serve."""
    mission = load_mission(row.mission, row)
    folder = out / row.folder
    shared, own = out / row.mission / "plan.json", folder / "plan.json"
    if shared.is_file() and not own.is_file():
        own.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shared, own)
    run = MissionRun(mission, stored_or_new_plan(mission, folder), folder)
    if not shared.is_file():
        shutil.copyfile(own, shared)
    jobs = run.jobs()
    if row.method == "g-rrt":
        jobs = jobs[:1]  # one agent for the whole lasso
    elif row.subtasks is not None:
        jobs = [jobs[k] for k in row.subtasks]
    return run, jobs


def train_job(run: MissionRun, job: SubtaskJob) -> dict[str, Any]:
    """One training job in a pool process (stored result when already finished)."""
    return run.train(job).to_json()


def assemble_row(row: Row, out: Path, pool: ProcessPoolExecutor) -> None:
    """Whole-mission rollouts of a finished row, hand-over repair (its jobs on ``pool``) and
    its ``bundle.zip``, as ``ltlnav train`` does."""
    from workers.training import TrainResult

    run, jobs = row_jobs(row, out)
    results = [
        TrainResult.from_json(json.loads((run.job_folder(j) / "result.json").read_text()))
        for j in jobs
    ]

    def train_all(batch: Sequence[SubtaskJob]) -> list[TrainResult]:
        futures = [pool.submit(train_job, run, job) for job in batch]
        return [TrainResult.from_json(f.result()) for f in futures]

    evaluation = run.evaluate(results)
    results, evaluation, repairs = run.repair(results, evaluation, train_all)
    done = run.finish(results, evaluation, repairs)
    for r in done.repairs:
        print(
            f"{row.folder} hand-over repair {r.round} of sub-tasks {r.subtasks}: mission "
            f"{r.success_before:.1%} -> {r.success_after:.1%} ({'kept' if r.kept else 'not kept'})",
            flush=True,
        )
    print(f"{row.folder}: mission success {done.evaluation.success_rate:.1%}", flush=True)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def _reaped(pool: ProcessPoolExecutor) -> Iterator[None]:
    """Kill the pool's training processes when the run is interrupted: a forkserver child
    outlives its parent and would go on training the jobs already handed to it."""
    try:
        yield
    except BaseException:
        # ProcessPoolExecutor has no public way to kill running jobs.
        for process in list(getattr(pool, "_processes", {}).values()):
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise


def run_rows(rows: list[Row], out: Path, jobs: int) -> None:
    """Train every row's jobs, ``jobs`` at a time, then roll out the complete rows."""
    context = training_context()
    planned = [(row, *row_jobs(row, out)) for row in rows]
    signal.signal(signal.SIGTERM, _interrupt)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool, _reaped(pool):
        pending: dict[Future[dict[str, Any]], tuple[Row, int]] = {}
        for row, run, row_specs in planned:
            for spec in row_specs:
                pending[pool.submit(train_job, run, spec)] = (row, spec.subtask)
        left = {row: sum(1 for r, _ in pending.values() if r == row) for row, *_ in planned}
        for future in as_completed(pending):
            row, k = pending[future]
            result = future.result()
            final = result.get("final") or {}
            print(
                f"{row.folder} sub-task {k}: {result['steps']} steps ({result['stopped']}), "
                f"success {final.get('success_rate', float('nan')):.1%}, "
                f"{result['seconds']:.0f} s",
                flush=True,
            )
            left[row] -= 1
            if left[row] == 0 and row.subtasks is None and row.method != "g-rrt":
                assemble_row(row, out, pool)  # here, not queued behind every other row's training


# ------------------------------------------------------------------------------------ report
def row_figures(row: Row, out: Path) -> dict[str, Any] | None:
    """What is on disk for ``row`` (None: not trained yet)."""
    folder = out / row.folder
    results = []
    for path in sorted(folder.glob("subtask_*/result.json"), key=lambda p: int(p.parent.name[8:])):
        k = int(path.parent.name[8:])
        if row.subtasks is not None and row.method != "g-rrt" and k not in row.subtasks:
            continue
        results.append(json.loads(path.read_text()))
    if not results:
        return None
    first_seconds = [r["seconds"] for r in results]
    repaired = folder / "handover_repair.json"
    rounds: list[dict[str, Any]] = []
    if repaired.is_file() and row.subtasks is None:  # the results kept after hand-over repair
        record = json.loads(repaired.read_text())
        results, rounds = record["results"], record["rounds"]
    bundle, mission = folder / "bundle.zip", None
    if bundle.is_file():  # written by assemble_row or by ``ltlnav train --out`` on the folder
        with zipfile.ZipFile(bundle) as archive:
            mission = json.loads(archive.read("manifest.json"))["mission_evaluation"]
    plan = json.loads((folder / "plan.json").read_text())["plan"]
    return {
        "results": results,
        "mission": mission,
        "n_subtasks": len(plan["subtasks"]),
        "first_seconds": first_seconds,
        "repairs": rounds,
    }


def _thousands(steps: int) -> str:
    """``5k`` for 5000 steps; ``0`` for a policy that met its target before training."""
    return f"{steps // 1000}k" if steps else "0"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def makespan(seconds: list[float], workers: int) -> float:
    """Wall time of running jobs of these durations on ``workers`` processes, in the given
    order, each job starting on the first free process (how the pool schedules them)."""
    free = [0.0] * workers
    for s in seconds:
        k = free.index(min(free))
        free[k] += s
    return max(free)


def table(rows: list[Row], out: Path, workers: int) -> str:
    """Table I: one line per row, then medians over seeds of ours."""
    header = (
        "| task | robot | method | seed | sub-tasks | success per sub-task (200 trials) | "
        "steps per sub-task | collisions | mission success (rollouts) | train s (sum) | "
        f"wall s ({workers} proc.) |"
    )
    lines = [header, "|" + "---|" * 11]
    for row in rows:
        fig = row_figures(row, out)
        mission = load_mission(row.mission, row)
        if fig is None:
            lines.append(
                f"| {row.mission} | {mission.robot.model} | {row.variant} | {row.seed} |"
                " not run | | | | | | |"
            )
            continue
        res = fig["results"]
        finals = [r.get("final") or {} for r in res]
        success = ", ".join(_pct(f.get("success_rate")) for f in finals)
        collisions = ", ".join(_pct(f.get("collision_rate")) for f in finals)
        steps = ", ".join(
            f"{_thousands(r['steps'])}{'' if r['stopped'] == 'target' else '*'}"
            + ("+h" if r.get("repairs") else "")
            for r in res
        )
        repairs = fig["repairs"]
        extra = sum(r["seconds"] for r in repairs)
        seconds = [r["seconds"] for r in res]
        wall = makespan(fig["first_seconds"], workers) + extra
        which = (
            "whole lasso"
            if row.method == "g-rrt"
            else ("all" if row.subtasks is None else "+".join(map(str, row.subtasks)))
        )
        if row.subtasks is None and row.method != "g-rrt" and len(res) < fig["n_subtasks"]:
            which = f"{len(res)} trained"
        ev = fig["mission"]
        ms = "-" if ev is None else f"{_pct(ev['success_rate'])} ({ev['episodes']})"
        if repairs:
            ms += f", {_pct(repairs[0]['success_before'])} before repair"
        lines.append(
            f"| {row.mission} | {mission.robot.model} | {row.variant} | {row.seed} | "
            f"{which} of {fig['n_subtasks']} | {success} | {steps} | {collisions} | {ms} | "
            f"{sum(seconds):.0f} | {wall:.0f} |"
        )
    lines.append("")
    lines.append(
        "`*`: the budget ran out before a periodic evaluation reached the target "
        "(no early stop). `+h`: trained on by hand-over repair (its success is then from the "
        "poses the mission's rollouts handed it over in). Wall: the pool's schedule of the "
        "measured job times, plus the hand-over repair rounds."
    )
    return "\n".join(lines)


def medians(rows: list[Row], out: Path) -> str:
    """Median over seeds per (mission, method), whole-mission rows only."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        fig = row_figures(row, out)
        if fig is not None and row.subtasks is None and fig["mission"] is not None:
            groups.setdefault((row.mission, row.variant), []).append(fig)
    lines = [
        "| task | method | seeds | median sub-task success | worst sub-task success | "
        "median steps to target | median mission success |",
        "|" + "---|" * 7,
    ]
    for (mission, method), figs in groups.items():
        rates = [
            (f.get("final") or {}).get("success_rate", 0.0) for fig in figs for f in fig["results"]
        ]
        steps = [r["steps"] for fig in figs for r in fig["results"]]
        whole = [fig["mission"]["success_rate"] for fig in figs]
        lines.append(
            f"| {mission} | {method} | {len(figs)} | {_pct(statistics.median(rates))} | "
            f"{_pct(min(rates))} | {statistics.median(steps):.0f} | "
            f"{_pct(statistics.median(whole))} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--preset", default="table1", choices=sorted(PRESETS))
    p.add_argument("--rows", nargs="*", type=Row.parse, help="mission:method:seed[:subs[:steps]]")
    p.add_argument("--out", default=str(ROOT / "var" / "bench" / "train"), help="run folders")
    p.add_argument("--jobs", type=int, default=2, help="training processes at once")
    p.add_argument("--env", help='training.env overrides of every row, JSON ({"heading_noise": 3})')
    p.add_argument(
        "--training", help='other training overrides of every row, JSON ({"handover_rounds": 0})'
    )
    p.add_argument("--report", action="store_true", help="print the table of what is on disk")
    args = p.parse_args(argv)
    rows = args.rows or PRESETS[args.preset]
    if args.env:
        overrides = tuple(sorted(json.loads(args.env).items()))
        rows = [dataclasses.replace(r, env=overrides) for r in rows]
    if args.training:
        overrides = tuple(sorted(json.loads(args.training).items()))
        rows = [dataclasses.replace(r, training=overrides) for r in rows]
    out = Path(args.out)
    if not args.report:
        run_rows(rows, out, args.jobs)
    print(table(rows, out, args.jobs))
    print()
    print(medians(rows, out))


if __name__ == "__main__":
    main()
