"""Generality: every robot trained on generated worlds it was never tuned for (issue 18).

Missions come from a generator of our own (``mission``): forests of balls, mazes of walls, rooms
joined by doors, random boxes (2D) and towers (3D), 10 to 60 m (mazes: up to 40 m), a start and
two goals placed at random in free space where a grid search finds them reachable for the
robot, and a formula of one of ``TASKS`` (sequence, any order, patrol, until, response, avoid a
region). Robots: ``ROBOTS`` (the point robot in 2D and 3D, the unicycle, the racecar, the
quadrotor).

Seeds: defaults were tuned on ``TUNING_SEEDS`` only; the figures are reported on
``REPORT_SEEDS``, a disjoint range fixed before any was measured. Mission ``i`` of a robot uses
generator seed ``REPORT_SEEDS[i]`` and cycles through the world kinds and tasks.

Each mission is trained as a user would: ``ltlnav train MISSION --out DIR --jobs N``, timed from
start to bundle, then ``ltlnav rollout DIR/bundle.zip --episodes 50 --seed 12345`` (fresh
rollouts on a seed no training decision used) with a picture. The table prints per robot:
missions, mission success (median, worst, share >= 90 %), sub-tasks met at step 0 by the
feed-forward controller alone (the control: those are not learned), env steps trained, wall
time, and failures by cause (collision, timeout, automaton rejection, planning). A grid of the
rollout pictures is written to ``OUT/<robot>.png``.

Run ``.venv/bin/python bench/generality.py [--robots point unicycle ...] [--missions 10]``
(hours on two cores: about 1-10 minutes a mission); finished missions are reused; ``--report``
re-prints what is on disk.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(Path(__file__).resolve().parent))  # after the packages: bench/planner.py

from random_worlds import KINDS, Document, _ball, maze, scattered_boxes  # noqa: E402

from planner.geometry.world import World  # noqa: E402
from planner.geometry.world_spec import WorldSpec  # noqa: E402
from planner.search.reachability import unreachable_regions  # noqa: E402

LTLNAV = Path(sys.executable).parent / "ltlnav"

TUNING_SEEDS = range(0, 100)
"""Generator seeds any default was tuned on (the point robot's feed-forward: maze seed 1)."""
REPORT_SEEDS = range(1000, 1100)
"""Generator seeds the figures are reported on (disjoint from ``TUNING_SEEDS``)."""

ROBOTS: dict[str, dict[str, Any]] = {
    "point": {"model": "point", "dims": 2, "radius": 0.2},
    "point3d": {"model": "point", "dims": 3, "radius": 0.2},
    "unicycle": {"model": "unicycle", "dims": 2, "radius": 0.2},
    "racecar": {"model": "racecar", "dims": 2, "radius": 0.3},
    "quadrotor": {"model": "quadrotor", "dims": 3, "radius": 0.2},
}
"""Robot name -> model, workspace dimension and radius."""

TASKS: dict[str, str] = {
    "sequence": "[]!obstacle && <>(g1 && <>g2)",
    "any-order": "[]!obstacle && <>g1 && <>g2",
    "patrol": "[]!obstacle && []<>g1 && []<>g2",
    "until": "[]!obstacle && (!g2 U g1) && <>g2",
    "response": "[]!obstacle && [](g1 -> <>g2) && []<>g1",
    "avoid": "[]!obstacle && []!hot && <>(g1 && <>g2)",
}


def boxes(rng: np.random.Generator) -> tuple[list[float], list[Document]]:
    """A square 2D world of 10 to 60 m with random boxes covering about 12 %."""
    size = float(rng.uniform(10, 60))
    count = int(0.12 * size * size / 2.25) + 1
    return [size, size], scattered_boxes(rng, size, count, (0.5, 2.5))


def mazes(rng: np.random.Generator) -> tuple[list[float], list[Document]]:
    """A maze of 4 to 8 cells of 2.5 to 5 m a side, walls 0.3 m."""
    return maze(rng, wall=0.3)


WORLDS_2D: dict[str, Callable[[np.random.Generator], tuple[list[float], list[Document]]]] = {
    "forest": KINDS["forest"],
    "maze": mazes,
    "rooms": KINDS["rooms"],
    "boxes": boxes,
}
WORLDS_3D = {"towers": KINDS["towers"]}


def _free(world: World, rng: np.random.Generator, clearance: float) -> np.ndarray:
    return np.asarray(world.sample_free(rng, 1, clearance)[0])


def mission(robot: str, index: int) -> Document:
    """Mission ``index`` of ``robot`` on report seed ``REPORT_SEEDS[index]``."""
    seed = REPORT_SEEDS[index]
    return generate(robot, seed, index)


def generate(robot: str, seed: int, index: int) -> Document:
    """The mission of generator ``seed``; ``index`` picks the world kind and the task."""
    spec = ROBOTS[robot]
    kinds = WORLDS_3D if spec["dims"] == 3 else WORLDS_2D
    kind = list(kinds)[index % len(kinds)]
    task_name = list(TASKS)[index % len(TASKS)]
    rng = np.random.default_rng(seed)
    extent, obstacles = kinds[kind](rng)
    radius = float(spec["radius"])
    base: Document = {
        "bounds": [[0.0, round(e, 3)] for e in extent],
        "obstacles": obstacles,
        "regions": {},
    }
    world = WorldSpec.model_validate(base).build()
    goal_r = 0.5 if spec["dims"] == 3 else 1.0
    start = _free(world, rng, radius + 0.5)
    regions: Document = {}
    wanted = ["g1", "g2", "hot"] if task_name == "avoid" else ["g1", "g2"]
    for _attempt in range(500):
        if len(regions) == len(wanted):
            break
        name = wanted[len(regions)]
        centre = _free(world, rng, goal_r + radius)
        others = [np.array(r["ball"]["center"]) for r in regions.values()]
        if np.linalg.norm(centre - start) < 2 * goal_r + 1 or any(
            np.linalg.norm(centre - o) < 2 * goal_r + 1 for o in others
        ):
            continue
        trial = {**regions, name: _ball(centre, goal_r)}
        built = WorldSpec.model_validate({**base, "regions": trial}).build()
        if name == "hot" or not unreachable_regions(built, start, radius, [name]):
            regions = trial
    start_pose = [round(float(v), 3) for v in start]
    if spec["model"] in ("unicycle", "racecar"):
        start_pose.append(round(float(rng.uniform(-np.pi, np.pi)), 3))
    return {
        "name": f"{robot}-{kind}-{task_name}-{seed}",
        "task": TASKS[task_name],
        "robot": {"model": spec["model"], "start": start_pose, "radius": radius},
        "planner": {"seed": 0},
        "world": {**base, "regions": regions},
    }


MAZE_SEEDS = range(100, 105)
"""Report seeds of ``issue_maze`` (the point robot's feed-forward was tuned on maze seed 1)."""


def issue_maze(seed: int) -> Document:
    """The maze of issue 18 for the point robot: 7 x 7 cells of 3 m (21 x 21 m), walls 0.3 m,
    start in one corner cell, ``<>(g1 && <>g2)`` with g1 in the opposite corner and g2 in a third
    one (the first guide winds 40-65 m through the maze)."""
    _, walls = maze(np.random.default_rng(seed), n=7, cell=3.0, wall=0.3)
    return {
        "name": f"point-maze-{seed}",
        "task": "[]!obstacle && <>(g1 && <>g2)",
        "robot": {"model": "point", "start": [1.5, 1.5], "radius": 0.2},
        "planner": {"seed": 0, "margin": 0.2},
        "world": {
            "bounds": [[0, 21], [0, 21]],
            "obstacles": walls,
            "regions": {
                "g1": {"ball": {"center": [19.5, 19.5], "radius": 0.8}},
                "g2": {"ball": {"center": [19.5, 1.5], "radius": 0.8}},
            },
        },
    }


def run_mission(robot: str, index: int, out: Path, jobs: int) -> None:
    """Train and roll out one mission unless its record is on disk."""
    doc = issue_maze(MAZE_SEEDS[index]) if robot == "point-maze" else mission(robot, index)
    folder = out / robot / doc["name"]
    record = folder / "record.json"
    if record.is_file():
        return
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "mission.yaml"
    path.write_text(yaml.safe_dump(doc))
    started = time.monotonic()
    train = [str(LTLNAV), "train", str(path), "--out", str(folder / "run"), "--jobs", str(jobs)]
    with open(folder / "train.log", "w") as log:
        code = subprocess.call(train, stdout=log, stderr=subprocess.STDOUT)
    seconds = time.monotonic() - started
    rollout_code = None
    bundle = folder / "run" / "bundle.zip"
    if bundle.is_file():
        rollout = [
            str(LTLNAV), "rollout", str(bundle), "--episodes", "50", "--seed", "12345",
            "--json", str(folder / "rollout.json"), "--plot", str(folder / "rollout.png"),
        ]  # fmt: skip
        with open(folder / "rollout.log", "w") as log:
            rollout_code = subprocess.call(rollout, stdout=log, stderr=subprocess.STDOUT)
    record.write_text(
        json.dumps({"seconds": seconds, "train_exit": code, "rollout_exit": rollout_code})
    )
    print(f"{robot} {doc['name']}: {seconds:.0f} s, train exit {code}", flush=True)


def _name(robot: str, index: int) -> str:
    if robot == "point-maze":
        return f"point-maze-{MAZE_SEEDS[index]}"
    return str(mission(robot, index)["name"])


def mission_figures(folder: Path) -> dict[str, Any] | None:
    """What one finished mission measured (None: not run yet)."""
    record = folder / "record.json"
    if not record.is_file():
        return None
    figures: dict[str, Any] = json.loads(record.read_text())
    rollout = folder / "rollout.json"
    figures["rollout"] = json.loads(rollout.read_text()) if rollout.is_file() else None
    results = [
        json.loads(p.read_text()) for p in sorted((folder / "run").glob("subtask_*/result.json"))
    ]
    figures["subtasks"] = len(results)
    figures["met_at_start"] = sum(1 for r in results if r["steps"] == 0)
    figures["steps"] = sum(r["steps"] for r in results)
    log = folder / "train.log"
    figures["reason"] = None
    if figures["train_exit"] != 0 and log.is_file():
        lines = [ln for ln in log.read_text().splitlines() if ln.strip()]
        figures["reason"] = lines[-1][:160] if lines else f"exit {figures['train_exit']}"
    return figures


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def report(robots: list[str], missions: int, out: Path) -> str:
    lines = [
        "| robot | missions | mission success median / worst | share >= 90 % | sub-tasks met "
        "at step 0 by the controller | env steps (median) | wall min (median) | failures by "
        "cause (rollouts) | not trained |",
        "|" + "---|" * 9,
    ]
    for robot in robots:
        rates: list[float] = []
        walls: list[float] = []
        steps: list[int] = []
        met = subtasks = 0
        causes = {"collision": 0.0, "timeout": 0.0, "rejected": 0.0}
        failed: list[str] = []
        for index in range(min(missions, len(MAZE_SEEDS)) if robot == "point-maze" else missions):
            name = _name(robot, index)
            fig = mission_figures(out / robot / name)
            if fig is None:
                continue
            walls.append(fig["seconds"] / 60)
            if fig["rollout"] is None:
                failed.append(f"{name}: {fig['reason']}")
                rates.append(0.0)
                continue
            roll = fig["rollout"]
            rates.append(float(roll["success_rate"]))
            steps.append(int(fig["steps"]))
            met += fig["met_at_start"]
            subtasks += fig["subtasks"]
            for cause in causes:
                causes[cause] += float(roll.get(f"{cause}_rate", 0.0)) * roll["episodes"]
        if not rates:
            continue
        share = sum(r >= 0.9 for r in rates) / len(rates)
        lines.append(
            f"| {robot} | {len(rates)} | {_pct(statistics.median(rates))} / {_pct(min(rates))} | "
            f"{_pct(share)} | {met} of {subtasks} | "
            f"{statistics.median(steps) if steps else 0:.0f} | {statistics.median(walls):.1f} | "
            + ", ".join(f"{k} {v:.0f}" for k, v in causes.items())
            + f" | {len(failed)} |"
        )
        lines.extend(f"|  | not trained: {reason} | | | | | | | |" for reason in failed)
    return "\n".join(lines)


def picture_grid(robot: str, missions: int, out: Path) -> Path | None:
    """The rollout pictures of ``robot``'s missions in one grid (None: none yet)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    count = min(missions, len(MAZE_SEEDS)) if robot == "point-maze" else missions
    pictures = [out / robot / _name(robot, i) / "rollout.png" for i in range(count)]
    pictures = [p for p in pictures if p.is_file()]
    if not pictures:
        return None
    cols = min(5, len(pictures))
    rows = (len(pictures) + cols - 1) // cols
    figure, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, picture in zip(axes.flat, pictures, strict=False):
        ax.imshow(plt.imread(picture))
        ax.set_title(picture.parent.name, fontsize=7)
    path = out / f"{robot}.png"
    figure.tight_layout()
    figure.savefig(path, dpi=80)
    plt.close(figure)
    return path


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--robots",
        nargs="*",
        default=list(ROBOTS),
        choices=[*ROBOTS, "point-maze"],
        help="robots (point-maze: the point robot on issue 18's maze, MAZE_SEEDS)",
    )
    p.add_argument("--missions", type=int, default=10, help="missions per robot")
    p.add_argument(
        "--first", type=int, default=0, help="train from this mission index on (a partial run)"
    )
    p.add_argument("--jobs", type=int, default=2, help="--jobs of ltlnav train")
    p.add_argument("--out", default=str(ROOT / "var" / "bench" / "generality"))
    p.add_argument("--report", action="store_true", help="print the table of what is on disk")
    args = p.parse_args(argv)
    out = Path(args.out)
    if not args.report:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        # Robot after robot per index: partial runs mix the robots.
        for index in range(args.first, args.missions):
            for robot in args.robots:
                if robot != "point-maze" or index < len(MAZE_SEEDS):
                    run_mission(robot, index, out, args.jobs)
    for robot in args.robots:
        picture_grid(robot, args.missions, out)
    print(report(args.robots, args.missions, out))


if __name__ == "__main__":
    main()
