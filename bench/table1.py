"""Table I of Cai et al. (RA-L 2023) complete: every row, every method, two protocols, the
control, evaluations nobody selected on (issue 19).

Rows (``TASKS``): phi_1,fin and phi_1,inf on the quadrotor, phi_2,fin and phi_2,inf on the car
(unicycle) and on the racecar, phi_3,fin and phi_3,inf (12 goals) on the quadrotor and on the
car. Columns: the reward methods ``rrt`` (ours), ``rrt-paper``, ``ned``,
``tl`` and ``g-rrt`` (one agent for the whole lasso, with every sub-task's budget), each on
``SEEDS``, and the control ``zero`` (the zero action: under ``shaped`` that is the robot's
feed-forward alone), evaluated like a policy. Protocols (``workers.training_spec.Protocol``):
``shaped`` (every method the identical env, only the reward differs) and ``paper`` (Cai et al.'s
env as published). One budget per row for every method (``TASKS``), no hand-over repair (it
would give the methods whose missions fail more steps than the budget).

Every run trains with ``bench/train.py``'s runner (the production ``MissionRun``) on the row's
one plan into ``OUT/<mission>/<method>+protocol=<p>.../seed<N>/``, one run after another, each
with ``--jobs`` processes, and its wall time from start to its last rollout is measured and
kept in ``wall.json``. The reported figures come from evaluations no decision used
(``workers.training``: the final 200 trials at ``seed + 2``; ``workers.run``: the rollouts at
``seed + 7``). Runs that finished are reused, so the command resumes. A finished run's figures
(sub-task and mission success, steps, wall time, the code it ran, its periodic evaluations) are
kept as small JSON in ``--records`` (``bench/table1/``, committed): the run folders hold models
and replay buffers and do not outlive the machine, the records do. ``--report`` re-prints
``TABLE1.md`` and the figures from the records and whatever run folders are on disk.

The whole table is 10 rows x 2 protocols x 5 methods x 3 seeds = 300 runs: at the budgets below
that is several days on two cores, so ``--rows``, ``--protocols``, ``--methods`` and
``--seeds`` choose a part (the default is everything).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from train import Row, load_mission, row_figures, row_jobs, run_rows  # noqa: E402

METHODS = ("rrt", "rrt-paper", "ned", "tl", "g-rrt")
PROTOCOLS = ("shaped", "paper")
SEEDS = (0, 1, 2)


@dataclass(frozen=True)
class Task:
    """One row of the table: an example mission and the budget of every method on it."""

    name: str
    label: str
    budget: int
    """Env steps per sub-task (``g-rrt``: times the number of sub-tasks, for its one agent)."""


TASKS = (
    Task("quad-phi1-fin", "phi_1,fin quadrotor", 30_000),
    Task("quad-phi1-inf", "phi_1,inf quadrotor", 30_000),
    Task("car-phi2-fin", "phi_2,fin car", 30_000),
    Task("car-phi2-inf", "phi_2,inf car", 30_000),
    Task("racecar-phi2-fin", "phi_2,fin racecar", 30_000),
    Task("racecar-phi2-inf", "phi_2,inf racecar", 30_000),
    Task("quad-phi3-fin", "phi_3,fin quadrotor", 20_000),
    Task("car-phi3-fin", "phi_3,fin car", 20_000),
    Task("quad-phi3-inf", "phi_3,inf quadrotor", 20_000),
    Task("car-phi3-inf", "phi_3,inf car", 20_000),
)
PAPER_FIGURES = "D-RRT* ~100 %, TL / NED / G-RRT* 0 %; 10k-20k episodes per task"
"""What the paper's Table I reports per row, for comparison (its own units: episodes)."""


STOP_RULES: tuple[tuple[str, Any], ...] = (("plateau_evals", None), ("pick_candidates", None))
"""Every run of the table stops at its target (confirmed) or its budget and keeps the best
periodic evaluation's policy, as all its records were made: the plateau stop and the pick, the
defaults since the twenty-fourth session, stay off here so that the rows remain one budget."""


def run_row(task: Task, method: str, protocol: str, seed: int) -> Row:
    """The bench/train.py row of one run."""
    training = (("handover_rounds", 0), ("protocol", protocol))
    return Row(task.name, method, seed, None, task.budget, training=training, fixed=STOP_RULES)


def subtask_count(task: Task, out: Path) -> int:
    _, jobs = row_jobs(run_row(task, "rrt", "shaped", 0), out)
    return len(jobs)


def train(
    task: Task, method: str, protocol: str, seed: int, out: Path, records: Path, jobs: int
) -> None:
    """Train one run unless its record or its ``wall.json`` says it finished (on this machine
    or another); measure its wall time and keep its record at once."""
    row = run_row(task, method, protocol, seed)
    if (records / f"{row.folder}.json").is_file():
        return
    if method == "g-rrt":
        row = replace(row, timesteps=task.budget * subtask_count(task, out))
    record = out / row.folder / "wall.json"
    if record.is_file():
        return
    commit, started = _commit(), time.monotonic()
    run_rows([row], out, jobs)
    spent = {"seconds": time.monotonic() - started, "jobs": jobs, "commit": commit}
    record.write_text(json.dumps(spent))
    run_figures(task, method, protocol, seed, out, records)


def zero_control(task: Task, protocol: str, out: Path, records: Path) -> dict[str, Any]:
    """The zero action evaluated like a policy on the row's plan (``workers.control``), kept in
    ``records``."""
    from workers.control import zero_control as control
    from workers.run import stored_or_new_plan

    record = _zero_record(task, protocol, records)
    if record.is_file():
        figures: dict[str, Any] = json.loads(record.read_text())
        return figures
    row = run_row(task, "rrt", protocol, 0)
    mission = load_mission(task.name, row)
    evaluation = control(mission, stored_or_new_plan(mission, out / row.folder))
    figures = {
        "subtasks": [e.success_rate for e in evaluation.subtasks],
        "mission": evaluation.mission.success_rate,
        "commit": _commit(),
    }
    record.parent.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(figures))
    return figures


def _zero_record(task: Task, protocol: str, records: Path) -> Path:
    return records / task.name / f"zero+protocol={protocol}.json"


def _commit() -> str:
    """The code the run was measured with (``git describe``; ``unknown`` outside a checkout)."""
    import subprocess

    try:
        return subprocess.run(
            ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _curve(folder: Path) -> dict[str, Any]:
    """Periodic evaluations of every sub-task: the steps and the success rate at each."""
    curve: dict[str, Any] = {}
    for npz in sorted(folder.glob("subtask_*/evaluations.npz")):
        data = np.load(npz)
        curve[npz.parent.name] = {
            "timesteps": [int(t) for t in data["timesteps"]],
            "success": [round(float(x), 4) for x in data["successes"].mean(axis=1)],
        }
    return curve


def run_figures(
    task: Task, method: str, protocol: str, seed: int, out: Path, records: Path
) -> dict[str, Any]:
    """Sub-task successes, steps, mission success, wall time and curves of a finished run ({}:
    not run). A finished run's figures are kept in ``records`` (small JSON, committed), so the
    table and its figures survive the run folders (models, replay buffers) being deleted."""
    row = run_row(task, method, protocol, seed)
    record = records / f"{row.folder}.json"
    if record.is_file():
        kept: dict[str, Any] = json.loads(record.read_text())
        return kept
    wall = out / row.folder / "wall.json"
    fig = row_figures(row, out)
    if fig is None or not wall.is_file():
        return {}
    results = fig["results"]
    spent = json.loads(wall.read_text())
    figures = {
        "subtasks": [(r.get("final") or {}).get("success_rate", 0.0) for r in results],
        "steps": [r["steps"] for r in results],
        "met": [r["stopped"] == "target" for r in results],
        "mission": None if fig["mission"] is None else fig["mission"]["success_rate"],
        "wall": spent["seconds"],
        "jobs": spent["jobs"],
        "commit": spent.get("commit", "unknown"),
        "curve": _curve(out / row.folder),
    }
    record.parent.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(figures, indent=1) + "\n")
    return figures


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def cell(runs: list[dict[str, Any]]) -> list[str]:
    """Median / worst sub-task success, missions per seed, median steps, median wall."""
    done = [r for r in runs if r]
    if not done:
        return ["not run"] * 5
    rates = [x for r in done for x in r["subtasks"]]
    missions = " / ".join(_pct(r["mission"]) for r in done)
    steps = [s for r in done for s in r["steps"]]
    walls = [r["wall"] for r in done]
    return [
        f"{_pct(statistics.median(rates))} ({_pct(min(rates))})",
        f"{missions} ({len(done)} seeds)",
        f"{statistics.median(steps) / 1000:.0f}k",
        f"{statistics.median(walls) / 60:.1f} min",
        f"{sum(1 for r in done for m in r['met'] if m)} of {sum(len(r['met']) for r in done)}",
    ]


def report(
    tasks: list[Task],
    methods: list[str],
    protocols: list[str],
    seeds: list[int],
    out: Path,
    records: Path,
) -> str:
    """``TABLE1.md``: one table per protocol, a line per (row, method) and the control."""
    lines = ["# Table I (bench/table1.py)", ""]
    for protocol in protocols:
        lines += [
            f"## Protocol `{protocol}`",
            "",
            "| task | budget / sub-task | method | sub-task success median (worst) | "
            "mission success per seed | median steps | median wall | sub-tasks met |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for task in tasks:
            for method in methods:
                runs = [run_figures(task, method, protocol, s, out, records) for s in seeds]
                lines.append(
                    f"| {task.label} | {task.budget // 1000}k | {method} | "
                    + " | ".join(cell(runs))
                    + " |"
                )
            zero = _zero_record(task, protocol, records)
            if zero.is_file():
                z = json.loads(zero.read_text())
                rates = z["subtasks"]
                lines.append(
                    f"| {task.label} | - | zero (control) | {_pct(statistics.median(rates))} "
                    f"({_pct(min(rates))}) | {_pct(z['mission'])} | 0 | - | - |"
                )
            lines.append(f"| {task.label} | paper | (Cai et al.) | {PAPER_FIGURES} | | | | |")
        lines.append("")
    return "\n".join(lines)


def method_curve(
    task: Task, method: str, protocol: str, seeds: list[int], out: Path, records: Path
) -> tuple[np.ndarray, np.ndarray] | None:
    """The steps of the periodic evaluations and, per seed and sub-task, the success rate at
    each (a run that stopped early holds its last rate, and a sub-task met at step 0, which
    trained not at all, holds its rate throughout; with no training at all the steps are 0 and
    the row's budget); None: no run yet."""
    series: list[np.ndarray] = []
    steps: np.ndarray | None = None
    held: list[float] = []
    for seed in seeds:
        run = run_figures(task, method, protocol, seed, out, records)
        curve = run.get("curve", {})
        for subtask in curve.values():
            if steps is None or len(subtask["timesteps"]) > len(steps):
                steps = np.asarray(subtask["timesteps"])
            series.append(np.asarray(subtask["success"]))
        spent = run.get("steps", [])
        for k, rate in enumerate(run.get("subtasks", [])):
            if spent[k] == 0 and f"subtask_{k}" not in curve:
                held.append(rate)
    if steps is None:
        if not held:
            return None
        steps = np.array([0, task.budget])
    series += [np.array([rate]) for rate in held]
    grid = np.full((len(series), len(steps)), np.nan)
    for i, s in enumerate(series):
        grid[i, : len(s)] = s
        grid[i, len(s) :] = s[-1]
    return steps, grid


def curves(
    task: Task,
    methods: list[str],
    protocol: str,
    seeds: list[int],
    out: Path,
    records: Path,
    path: Path,
) -> None:
    """Success rate against env steps, per method: median over seeds and sub-tasks of the
    periodic evaluations, band from min to max; the control (the feed-forward or zero action
    alone, no training) as a dashed line at its median sub-task success."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 4))
    for method in methods:
        curve = method_curve(task, method, protocol, seeds, out, records)
        if curve is None:
            continue
        steps, grid = curve
        axes.plot(steps, np.nanmedian(grid, axis=0), label=method)
        axes.fill_between(steps, np.nanmin(grid, axis=0), np.nanmax(grid, axis=0), alpha=0.2)
    zero = _zero_record(task, protocol, records)
    if axes.lines and zero.is_file():
        rate = statistics.median(json.loads(zero.read_text())["subtasks"])
        axes.axhline(rate, color="black", linestyle="--", label="zero (control)")
    axes.set(xlabel="env steps", ylabel="success rate", title=f"{task.label} ({protocol})")
    axes.set_ylim(-0.02, 1.02)
    if axes.lines:
        axes.legend()
    else:
        axes.text(0.5, 0.5, "no run yet", ha="center", transform=axes.transAxes)
    figure.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(figure)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rows", nargs="*", default=[t.name for t in TASKS], help="example names")
    p.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    p.add_argument("--protocols", nargs="*", default=list(PROTOCOLS), choices=PROTOCOLS)
    p.add_argument("--seeds", nargs="*", type=int, default=list(SEEDS))
    p.add_argument("--jobs", type=int, default=2, help="training processes per run")
    p.add_argument("--out", type=Path, default=ROOT / "var" / "bench" / "table1")
    p.add_argument(
        "--records",
        type=Path,
        help="the finished runs' figures (small JSON; the table is printed from them); default "
        "bench/table1/, or OUT/records with --budget (a smoke run's must not pass for the table's)",
    )
    p.add_argument("--budget", type=int, help="steps per sub-task of every row (smoke runs)")
    p.add_argument("--report", action="store_true", help="re-print TABLE1.md from disk")
    args = p.parse_args(argv)
    tasks = [t for t in TASKS if t.name in args.rows]
    if args.budget is not None:
        tasks = [Task(t.name, t.label, args.budget) for t in tasks]
    if args.records is None:
        args.records = ROOT / "bench" / "table1" if args.budget is None else args.out / "records"
    if not args.report:
        for task in tasks:
            for protocol in args.protocols:
                zero_control(task, protocol, args.out, args.records)
                for seed in args.seeds:
                    for method in args.methods:
                        train(task, method, protocol, seed, args.out, args.records, args.jobs)
    text = report(tasks, args.methods, args.protocols, args.seeds, args.out, args.records)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "TABLE1.md").write_text(text)
    for task in tasks:
        for protocol in args.protocols:
            picture = args.out / f"{task.name}-{protocol}.png"
            curves(task, args.methods, protocol, args.seeds, args.out, args.records, picture)
    print(text)


if __name__ == "__main__":
    main()
