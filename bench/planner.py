"""Planner benchmark: translation, first lasso, anytime cost, and the outside references.

Run with ``make bench`` or ``.venv/bin/python bench/planner.py [--seeds N] [--quick]
[--random N] [--baseline TREE]``. Times are CPU seconds (``time.process_time``): this machine is
shared and wall time is noisy. Prints one table per group: the reference workspace of TL-RRT*
side by side with the reference figures measured on this machine, the paper's examples, the
missions of ``bench/missions`` and seeded random missions (``bench/random_worlds.py``: forests,
mazes, rooms with doors, 3D towers; 10 to 60 m; 3 to 12 goals; finite and infinite tasks).

``--baseline TREE`` plans every mission and seed also with the planner of another checkout
(e.g. ``git archive HEAD~3 | tar -x -C /tmp/old``), alternating the two in fresh interpreters,
and prints old and new side by side with their time ratio. ``--quick`` keeps a run to about
a minute of CPU: one seed per mission, two per reference task, four random missions, no OMPL.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from random_worlds import suite  # noqa: E402

from planner.ltl.formula import parse  # noqa: E402
from planner.ltl.translate import translate  # noqa: E402
from workers.mission import MissionSpec, load_mission  # noqa: E402

SHARED = ROOT.parent / "shared" / "benchmarks"
"""The benchmarks from outside the project (falls back to the copies in examples/)."""

EXAMPLES = [
    "car-phi2-fin",
    "car-phi2-inf",
    "car-phi3-fin",
    "car-phi3-inf",
    "racecar-phi2-fin",
    "racecar-phi2-inf",
    "quad-phi1-fin",
    "quad-phi1-inf",
    "quad-phi3-fin",
    "quad-phi3-inf",
]
REFERENCE_TLRRT = {  # XushengLuo/TLRRT_star measured here: median (range) over 20 seeds
    "tlrrt-gf3": ("0.21 (0.10-0.71)", "1.79 (1.58-2.52)"),
    "tlrrt-case1": ("0.20 (0.09-0.57)", "1.13 (0.82-1.59)"),
}
"""Its workspaces are planned for a point of radius 0 with no margin, as the reference plans."""
LTL2BA_SIZES = {
    "car-phi2-fin": "5 / 15",
    "car-phi2-inf": "9 / 43",
    "quad-phi1-fin": "8 / 27",
    "quad-phi1-inf": "4 / 13",
    "car-phi3-fin": "13 / 90",
    "quad-phi3-fin": "13 / 90",
    "quad-phi3-inf": "13 / >10 min",
}


@dataclass
class Run:
    """One mission and seed: the first lasso (no anytime phase, no shortcut) and the plan with
    the mission's own planner options."""

    first_seconds: float
    first_cost: float
    final_seconds: float
    final_cost: float
    subtasks: int
    valid: bool


# Plans one mission and seed with the planner of the tree on sys.path and prints a Run as JSON;
# run in a fresh interpreter for --baseline (old trees know nothing of this file).
WORKER = """
import json, sys, time
from planner.errors import PlanningError
from planner.plan import plan_mission, verify_plan
from workers.mission import load_mission

spec = load_mission(sys.argv[1])
seed = int(sys.argv[2])
world = spec.build_world()
start, radius = spec.robot.position(), spec.robot.radius
options = spec.planner_options()
if len(sys.argv) > 3:
    options = options.model_copy(update={"margin": float(sys.argv[3])})
first_options = options.model_copy(update={"seed": seed, "refine_seconds": 0.0, "shortcut": False})
final_options = options.model_copy(update={"seed": seed})
try:
    began = time.process_time()
    first = plan_mission(world, spec.task, start, radius, first_options)
    first_seconds = time.process_time() - began
    began = time.process_time()
    final = plan_mission(world, spec.task, start, radius, final_options)
    final_seconds = time.process_time() - began
except PlanningError as error:
    print(json.dumps({"error": str(error)}))
    sys.exit(0)
valid = not verify_plan(first, world, radius) and not verify_plan(final, world, radius)
print(json.dumps({
    "first_seconds": first_seconds, "first_cost": first.lasso.cost,
    "final_seconds": final_seconds, "final_cost": final.lasso.cost,
    "subtasks": len(final.subtasks), "valid": valid,
}))
"""


def run_once(mission: Path, seed: int, tree: Path = ROOT) -> Run | None:
    """Plan ``mission`` with ``seed`` using the planner of checkout ``tree`` (fresh interpreter)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    margin = ["0"] if mission.stem in REFERENCE_TLRRT else []
    out = subprocess.run(
        [sys.executable, "-c", WORKER, str(mission), str(seed), *margin],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    lines = out.stdout.strip().splitlines()
    if out.returncode != 0 or not lines:
        print(
            f"  {mission.stem} seed {seed} ({tree}): crashed\n{out.stderr[-2000:]}", file=sys.stderr
        )
        return None
    result = json.loads(lines[-1])
    if "error" in result:
        print(f"  {mission.stem} seed {seed} ({tree}): no plan: {result['error']}", file=sys.stderr)
        return None
    return Run(**result)


def spread(values: Sequence[float], digits: int = 2) -> str:
    """Median and range, as the reference figures are given."""
    if not values:
        return "-"
    median, low, high = statistics.median(values), min(values), max(values)
    return f"{median:.{digits}f} ({low:.{digits}f}-{high:.{digits}f})"


def translation_row(name: str, spec: MissionSpec) -> list[str]:
    formula = parse(spec.task)
    began = time.perf_counter()
    automaton = translate(formula)
    seconds = time.perf_counter() - began
    return [
        name,
        f"{automaton.num_states} / {automaton.num_transitions}",
        LTL2BA_SIZES.get(name, "-"),
        f"{seconds * 1000:.0f}",
    ]


def _summary(runs: Sequence[Run], seeds: int) -> list[str]:
    return [
        f"{len(runs)}/{seeds}",
        spread([r.first_seconds for r in runs]),
        spread([r.first_cost for r in runs]),
        spread([r.final_cost for r in runs]),
        spread([r.final_seconds for r in runs]),
        "yes" if runs and all(r.valid for r in runs) else "NO",
    ]


def mission_rows(
    missions: Sequence[Path], seeds: int, baseline: Path | None, record: list[dict[str, object]]
) -> list[list[str]]:
    """One row per mission; with a baseline tree, its figures beside ours and the time ratio."""
    rows = []
    for mission in missions:
        runs: list[Run] = []
        old: list[Run] = []
        for seed in range(seeds):
            if baseline is not None and (run := run_once(mission, seed, baseline)) is not None:
                old.append(run)
                record.append({"mission": mission.stem, "seed": seed, "tree": "old", **asdict(run)})
            if (run := run_once(mission, seed)) is not None:
                runs.append(run)
                record.append({"mission": mission.stem, "seed": seed, "tree": "new", **asdict(run)})
        reference = REFERENCE_TLRRT.get(mission.stem, ("-", "-"))
        if baseline is None:
            rows.append([mission.stem, *_summary(runs, seeds), reference[0], reference[1]])
            continue
        ratio = (
            statistics.median(r.final_seconds for r in runs)
            / statistics.median(r.final_seconds for r in old)
            if runs and old
            else float("nan")
        )
        rows.append(
            [
                mission.stem,
                f"{len(old)}/{len(runs)}/{seeds}",
                spread([r.first_seconds for r in old]),
                spread([r.first_seconds for r in runs]),
                spread([r.final_seconds for r in old]),
                spread([r.final_seconds for r in runs]),
                f"{ratio:.2f}",
                spread([r.final_cost for r in old]),
                spread([r.final_cost for r in runs]),
                "yes" if runs and all(r.valid for r in runs) else "NO",
            ]
        )
    return rows


def print_table(title: str, header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows, strict=True)]
    print(f"\n## {title}\n", flush=True)
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for row in rows:
        print("| " + " | ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)) + " |")
    sys.stdout.flush()


HEADER = [
    "mission",
    "solved",
    "first lasso CPU s",
    "first cost",
    "cost after budget",
    "CPU s with budget",
    "valid",
]
BASELINE_HEADER = [
    "mission",
    "solved old/new",
    "first s old",
    "first s new",
    "CPU s old",
    "CPU s new",
    "new/old",
    "cost old",
    "cost new",
    "valid",
]


def shared(name: str) -> Path:
    path = SHARED / f"{name}.yaml"
    return path if path.exists() else ROOT / "examples" / f"{name}.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=5, help="seeds per mission")
    parser.add_argument(
        "--reference-seeds", type=int, default=20, help="seeds per reference-workspace task"
    )
    parser.add_argument(
        "--random", type=int, default=12, help="random missions (bench/random_worlds)"
    )
    parser.add_argument("--random-seed", type=int, default=0, help="seed of the random suite")
    parser.add_argument(
        "--baseline", type=Path, help="another checkout whose planner runs side by side"
    )
    parser.add_argument("--only", nargs="*", help="only the missions with these names")
    parser.add_argument("--record", type=Path, help="write every run as JSON lines here")
    parser.add_argument(
        "--quick", action="store_true", help="1 seed each, 2 per reference task, 4 random, no OMPL"
    )
    args = parser.parse_args()
    seeds = 1 if args.quick else args.seeds
    reference_seeds = 2 if args.quick else args.reference_seeds
    random_count = min(args.random, 4) if args.quick else args.random
    record: list[dict[str, object]] = []

    examples = [ROOT / "examples" / f"{n}.yaml" for n in EXAMPLES]
    examples = [p for p in examples if p.exists()]
    ours = sorted((ROOT / "bench" / "missions").glob("*.yaml"))
    scratch = Path(tempfile.mkdtemp(prefix="ltlnav-bench-"))
    generated = []
    for spec in suite(random_count, args.random_seed):
        path = scratch / f"{spec.name}.json"
        path.write_text(spec.model_dump_json(exclude_none=True))
        generated.append(path)

    def keep(paths: list[Path]) -> list[Path]:
        return [p for p in paths if not args.only or p.stem in args.only]

    uname = os.uname()
    load = os.getloadavg()
    print(
        f"machine: {uname.nodename} {uname.machine}, {os.cpu_count()} CPUs, load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at start"
    )
    if not args.only:
        print_table(
            "Translation (ours vs ltl2ba 1.1 states / transitions)",
            ["mission", "ours", "ltl2ba", "ms"],
            [translation_row(p.stem, load_mission(p)) for p in examples],
        )
    header = [*HEADER, "ref first s", "ref cost"] if args.baseline is None else BASELINE_HEADER
    groups = [
        (
            f"TL-RRT* on the reference workspace ({reference_seeds} seeds; cost = 0.2 prefix "
            "+ 0.8 suffix; ref = XushengLuo/TLRRT_star on this machine)",
            keep([shared("tlrrt-gf3"), shared("tlrrt-case1")]),
            reference_seeds,
        ),
        (f"TL-RRT* on the paper's examples ({seeds} seeds)", keep(examples), seeds),
        (f"TL-RRT* on bench/missions ({seeds} seeds)", keep(ours), seeds),
        (
            f"TL-RRT* on random missions (suite seed {args.random_seed}, {seeds} planner seeds)",
            keep(generated),
            seeds,
        ),
    ]
    for title, missions, n in groups:
        if missions and n > 0:
            print_table(title, header, mission_rows(missions, n, args.baseline, record))
    if args.record is not None:
        args.record.write_text("".join(json.dumps(r) + "\n" for r in record))
    load = os.getloadavg()
    print(f"\nload average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the end")
    if not args.quick and not args.only:
        try:
            import rrt_vs_ompl
        except ImportError as error:
            print(f"\nOMPL comparison skipped: {error}")
        else:
            rrt_vs_ompl.main()


if __name__ == "__main__":
    main()
