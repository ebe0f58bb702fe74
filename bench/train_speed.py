"""Training wall time of training levers, side by side in one run (issue 17, item 3).

Each variant is a set of ``training`` overrides of an example mission (``{}``: the current
defaults; a ``planner`` key overrides the planner section, e.g. ``leg_length``). Every (mission,
seed) is trained by every variant one after another, seed by seed, as a user would: ``ltlnav
train MISSION --out DIR --jobs N`` in a fresh process, timed from start to ``bundle.zip``. A
variant without planner overrides runs on the same plan as the others (the planner is
deterministic for the mission's seed, issue 17 item 2), so only the lever differs.

The table prints, per row: wall time, mission success (the bundle's rollouts), per sub-task
steps and final success, and the learner's throughput (env steps trained per job second,
evaluations included); then per variant the median over seeds and the ratio of its wall time to
the first variant's on the same seeds; then where the time of each row's slowest job went
(the learner, periodic evaluations, confirmations, the start check, the final evaluation,
checkpoints: ``TrainResult.parts``).

Run ``.venv/bin/python bench/train_speed.py`` (the car mission, three variants, seeds 0-2;
about an hour on two cores) or ``--missions``, ``--variants NAME=JSON ...``, ``--seeds``;
``--report`` re-prints what is on disk. Finished rows are reused. ``--evaluation-cost
OUT/<mission>/<variant>/seed<N>`` times a finished row's policies' 200-episode evaluations
one episode after another against 10 lanes (CPU seconds, alternated twice); ``--rollout-cost
MISSION FOLDER`` times a finished ``ltlnav train``'s whole-mission rollouts in one process
against the lanes shared out over ``--jobs`` processes.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
LTLNAV = Path(sys.executable).parent / "ltlnav"

VARIANTS: dict[str, dict[str, Any]] = {
    "before": {"eval_lanes": 1, "hyperparams": {"train_freq": 1}},
    "lanes+tf2": {"eval_lanes": 10, "hyperparams": {"train_freq": 2}},
    "lanes": {"eval_lanes": 10, "hyperparams": {"train_freq": 1}},
}
"""``before``: the defaults before issue 17 (one evaluation episode after another, a gradient
step every env step); ``lanes+tf2``: evaluations in 10 lanes and one gradient step every second
env step (replay ratio 1/2); ``lanes``: the lanes alone."""


def mission_path(name: str) -> Path:
    """The example called ``name``, else the bench mission."""
    example = ROOT / "examples" / f"{name}.yaml"
    return example if example.is_file() else ROOT / "bench" / "missions" / f"{name}.yaml"


def mission_file(mission: str, overrides: dict[str, Any], seed: int, folder: Path) -> Path:
    """The example (or bench mission) with the variant's training overrides (its ``planner``
    key: planner overrides) and the seed, written to ``folder``."""
    document = yaml.safe_load(mission_path(mission).read_text())
    training = document.setdefault("training", {})
    for key, value in overrides.items():
        if key == "planner":
            document.setdefault("planner", {}).update(value)
        elif isinstance(value, dict):
            training.setdefault(key, {}).update(value)
        else:
            training[key] = value
    training["seed"] = seed
    path = folder / "mission.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def run_row(mission: str, variant: str, seed: int, out: Path, jobs: int) -> None:
    """Train one row unless its timing is on disk."""
    folder = out / mission / variant / f"seed{seed}"
    timing = folder / "timing.json"
    if timing.is_file():
        return
    folder.mkdir(parents=True, exist_ok=True)
    path = mission_file(mission, VARIANTS[variant], seed, folder)
    started = time.monotonic()
    command = [str(LTLNAV), "train", str(path), "--out", str(folder / "run"), "--jobs", str(jobs)]
    with open(folder / "train.log", "w") as log:
        code = subprocess.call(command, stdout=log, stderr=subprocess.STDOUT)
    seconds = time.monotonic() - started
    timing.write_text(json.dumps({"seconds": seconds, "exit_code": code, "jobs": jobs}))
    print(f"{mission} {variant} seed {seed}: {seconds:.0f} s, exit code {code}", flush=True)


def row_figures(folder: Path) -> dict[str, Any] | None:
    """Wall time, mission success and the jobs' results of a finished row."""
    timing = folder / "timing.json"
    if not timing.is_file():
        return None
    figures: dict[str, Any] = json.loads(timing.read_text())
    bundle = folder / "run" / "bundle.zip"
    figures["mission"] = None
    if bundle.is_file():
        with zipfile.ZipFile(bundle) as archive:
            figures["mission"] = json.loads(archive.read("manifest.json"))["mission_evaluation"]
    figures["jobs_results"] = [
        json.loads(p.read_text())
        for p in sorted((folder / "run").glob("subtask_*/result.json"), key=lambda p: p.parent.name)
    ]
    return figures


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def report(missions: list[str], variants: list[str], seeds: list[int], out: Path) -> str:
    lines = [
        "| mission | variant | seed | wall s | mission success | steps per sub-task | "
        "sub-task success | steps per job-second |",
        "|" + "---|" * 8,
    ]
    summary = [
        "| mission | variant | seeds | median wall s | wall / first variant | "
        "median mission success | worst mission success |",
        "|" + "---|" * 7,
    ]
    for mission in missions:
        walls: dict[str, dict[int, float]] = {}
        for variant in variants:
            successes: list[float] = []
            for seed in seeds:
                fig = row_figures(out / mission / variant / f"seed{seed}")
                if fig is None:
                    continue
                results = fig["jobs_results"]
                steps = sum(r["steps"] - r["resumed_from"] for r in results)
                job_seconds = sum(r["seconds"] for r in results)
                rate = None if fig["mission"] is None else fig["mission"]["success_rate"]
                if rate is not None:
                    successes.append(rate)
                walls.setdefault(variant, {})[seed] = fig["seconds"]
                lines.append(
                    f"| {mission} | {variant} | {seed} | {fig['seconds']:.0f} | {_pct(rate)} | "
                    + ", ".join(f"{r['steps'] // 1000}k" for r in results)
                    + " | "
                    + ", ".join(_pct((r.get("final") or {}).get("success_rate")) for r in results)
                    + f" | {steps / max(job_seconds, 1e-9):.0f} |"
                )
            mine = walls.get(variant, {})
            if not mine:
                continue
            first = walls.get(variants[0], {})
            shared = [s for s in mine if s in first]
            ratio = (
                f"{statistics.median(mine[s] / first[s] for s in shared):.2f}" if shared else "-"
            )
            summary.append(
                f"| {mission} | {variant} | {len(mine)} | {statistics.median(mine.values()):.0f} "
                f"| {ratio} | {_pct(statistics.median(successes) if successes else None)} | "
                f"{_pct(min(successes) if successes else None)} |"
            )
    return (
        "\n".join(lines)
        + "\n\n"
        + "\n".join(summary)
        + "\n\n"
        + slowest_jobs(missions, variants, seeds, out)
    )


def slowest_jobs(missions: list[str], variants: list[str], seeds: list[int], out: Path) -> str:
    """Where the time of each row's slowest job went (``TrainResult.parts``; jobs run in
    parallel, so the slowest is the one the bundle waits for)."""
    sys.path.insert(0, str(ROOT))
    from workers.stopwatch import largest_first

    lines = [
        "Slowest job of each row, wall seconds by part:",
        "",
        "| mission | variant | seed | sub-task | job s | by part |",
        "|" + "---|" * 6,
    ]
    for mission in missions:
        for variant in variants:
            for seed in seeds:
                fig = row_figures(out / mission / variant / f"seed{seed}")
                if fig is None or not fig["jobs_results"]:
                    continue
                job = max(fig["jobs_results"], key=lambda r: r["seconds"])
                lines.append(
                    f"| {mission} | {variant} | {seed} | {job['subtask']} | "
                    f"{job['seconds']:.0f} | {largest_first(job.get('parts') or {}) or '-'} |"
                )
    return "\n".join(lines)


def evaluation_cost(folder: Path, lanes: int = 10, episodes: int = 200) -> str:
    """CPU seconds of a final evaluation of each trained sub-task policy of a finished row
    (``folder``: a row's folder), one episode after another against ``lanes`` lanes,
    alternated twice."""
    sys.path.insert(0, str(ROOT))
    import torch

    from workers.agents import ALGORITHMS
    from workers.evaluation import evaluate_subtask
    from workers.mission import load_mission
    from workers.policy_act import deterministic_act
    from workers.run import stored_or_new_plan
    from workers.training import subtask_env

    torch.set_num_threads(1)
    mission = load_mission(folder / "mission.yaml")
    plan = stored_or_new_plan(mission, folder / "run")
    cls = ALGORITHMS[mission.training.algorithm]
    lines = [f"| sub-task | 1 lane, CPU s | {lanes} lanes, CPU s | success (1 / {lanes}) |",
             "|---|---|---|---|"]  # fmt: skip
    for k in range(len(plan.subtasks)):
        model = cls.load(folder / "run" / f"subtask_{k}" / "model.zip", device="cpu")

        act = deterministic_act(model.policy)
        envs = [subtask_env(mission, plan, mission.training, k, True) for _ in range(lanes)]
        seconds: dict[int, list[float]] = {1: [], lanes: []}
        rates: dict[int, float] = {}
        for n in (1, lanes, 1, lanes):
            started = time.process_time()
            result = evaluate_subtask(act, envs[0] if n == 1 else envs[:n], episodes, seed=2)
            seconds[n].append(time.process_time() - started)
            rates[n] = result.success_rate
        lines.append(
            f"| {k} | {min(seconds[1]):.1f} | {min(seconds[lanes]):.1f} | "
            f"{_pct(rates[1])} / {_pct(rates[lanes])} |"
        )
        for env in envs:
            env.close()
    return "\n".join(lines)


def rollout_cost(mission_file: Path, folder: Path, processes: int) -> str:
    """Wall seconds of a finished run's whole-mission evaluation (``ltlnav train MISSION --out
    FOLDER``: its ``training.mission_episodes`` rollouts on the deciding seed) in this process
    against its lanes shared out over a pool of ``processes`` (started before the clock, as
    ``ltlnav train``'s is), alternated twice."""
    sys.path.insert(0, str(ROOT))
    from concurrent.futures import ProcessPoolExecutor

    from workers.mission import load_mission
    from workers.pipeline import training_context
    from workers.run import MissionRun, Spread
    from workers.training import TrainResult

    run = MissionRun.open(load_mission(mission_file), folder)
    results = [
        TrainResult.from_json(json.loads((run.job_folder(job) / "result.json").read_text()))
        for job in run.jobs()
    ]
    context = training_context()
    seconds: dict[str, list[float]] = {"one process": [], f"{processes} processes": []}
    rates: dict[str, float] = {}
    with ProcessPoolExecutor(max_workers=processes, mp_context=context) as pool:
        list(pool.map(abs, range(processes)))  # the processes are up
        for name in [*seconds, *seconds]:
            run.spread = None if name == "one process" else Spread(pool.map, processes)
            started = time.perf_counter()
            evaluation = run.evaluate(results)
            seconds[name].append(time.perf_counter() - started)
            rates[name] = evaluation.success_rate
    lines = ["| rollouts of the whole mission | wall s (best of 2) | success |", "|---|---|---|"]
    episodes = run.training.mission_episodes
    for name, times in seconds.items():
        lines.append(f"| {episodes} in {name} | {min(times):.1f} | {_pct(rates[name])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--missions",
        nargs="*",
        default=["car-phi2-fin"],
        help="names of examples or of bench/missions files",
    )
    p.add_argument("--variants", nargs="*", help="NAME=JSON training overrides (default: ours)")
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    p.add_argument("--jobs", type=int, default=2, help="--jobs of ltlnav train")
    p.add_argument("--out", default=str(ROOT / "var" / "bench" / "speed"))
    p.add_argument("--report", action="store_true", help="print the table of what is on disk")
    p.add_argument(
        "--evaluation-cost",
        type=Path,
        help="a finished row's folder: time its policies' evaluations in 1 and 10 lanes",
    )
    p.add_argument(
        "--rollout-cost",
        nargs=2,
        type=Path,
        metavar=("MISSION", "FOLDER"),
        help="a finished `ltlnav train MISSION --out FOLDER`: time its mission rollouts in one "
        "process and over --jobs processes",
    )
    args = p.parse_args(argv)
    if args.rollout_cost is not None:
        mission_file, folder = args.rollout_cost
        print(rollout_cost(mission_file, folder, args.jobs))
        return
    if args.evaluation_cost is not None:
        print(evaluation_cost(args.evaluation_cost))
        return
    for text in args.variants or []:
        name, _, overrides = text.partition("=")
        VARIANTS[name] = json.loads(overrides)
    variants = [t.partition("=")[0] for t in args.variants] if args.variants else list(VARIANTS)
    out = Path(args.out)
    if not args.report:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        for mission in args.missions:
            for seed in args.seeds:
                for variant in variants:
                    run_row(mission, variant, seed, out, args.jobs)
    print(report(args.missions, variants, args.seeds, out))


if __name__ == "__main__":
    main()
