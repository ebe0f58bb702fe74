"""Planner benchmark: translation, first lasso, anytime cost, and the outside references.

Run with ``make bench`` or ``.venv/bin/python bench/planner.py [--seeds N] [--quick]``.
Times are CPU seconds (``time.process_time``): this machine is shared and wall time is noisy.
Prints one table per group, side by side with the reference figures measured on this machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planner.errors import PlanningError  # noqa: E402
from planner.ltl.formula import parse  # noqa: E402
from planner.ltl.translate import translate  # noqa: E402
from planner.plan import plan_mission, verify_plan  # noqa: E402
from workers.mission import MissionSpec, load_mission  # noqa: E402

EXAMPLES = [
    "car-phi2-fin",
    "car-phi2-inf",
    "quad-phi1-fin",
    "quad-phi1-inf",
    "quad-phi3-fin",
    "quad-phi3-inf",
]
REFERENCE_TLRRT = {  # XushengLuo/TLRRT_star measured here: median (range) over 20 seeds
    "tlrrt-gf3": ("0.21 (0.10-0.71)", "1.79 (1.58-2.52)"),
    "tlrrt-case1": ("0.20 (0.09-0.57)", "1.13 (0.82-1.59)"),
}
LTL2BA_SIZES = {
    "car-phi2-fin": "5 / 15",
    "car-phi2-inf": "9 / 43",
    "quad-phi1-fin": "8 / 27",
    "quad-phi1-inf": "4 / 13",
    "quad-phi3-fin": "13 / 90",
    "quad-phi3-inf": "13 / >10 min",
}


@dataclass
class Run:
    first_seconds: float
    first_cost: float
    final_seconds: float
    final_cost: float
    subtasks: int
    valid: bool


def spread(values: Sequence[float], digits: int = 2) -> str:
    """Median and range, as the reference figures are given."""
    if not values:
        return "-"
    median, low, high = statistics.median(values), min(values), max(values)
    return f"{median:.{digits}f} ({low:.{digits}f}-{high:.{digits}f})"


def run_once(spec: MissionSpec, seed: int) -> Run | None:
    world = spec.build_world()
    start, radius = spec.robot.position(), spec.robot.radius
    first_options = spec.planner.model_copy(
        update={"seed": seed, "refine_seconds": 0.0, "shortcut": False}
    )
    final_options = spec.planner.model_copy(update={"seed": seed})
    try:
        began = time.process_time()
        first = plan_mission(world, spec.task, start, radius, first_options)
        first_seconds = time.process_time() - began
        began = time.process_time()
        final = plan_mission(world, spec.task, start, radius, final_options)
        final_seconds = time.process_time() - began
    except PlanningError as error:
        print(f"  seed {seed}: no plan: {error}", file=sys.stderr)
        return None
    valid = not verify_plan(first, world, radius) and not verify_plan(final, world, radius)
    return Run(
        first_seconds, first.lasso.cost, final_seconds, final.lasso.cost, len(final.subtasks), valid
    )


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


def mission_rows(names: Sequence[str], seeds: int) -> list[list[str]]:
    rows = []
    for name in names:
        spec = load_mission(ROOT / "examples" / f"{name}.yaml")
        runs = [run for seed in range(seeds) if (run := run_once(spec, seed)) is not None]
        first_time, first_cost, final_cost = (
            [r.first_seconds for r in runs],
            [r.first_cost for r in runs],
            [r.final_cost for r in runs],
        )
        reference = REFERENCE_TLRRT.get(name, ("-", "-"))
        rows.append(
            [
                name,
                f"{len(runs)}/{seeds}",
                spread(first_time),
                spread(first_cost),
                spread(final_cost),
                spread([r.final_seconds for r in runs]),
                reference[0],
                reference[1],
                "yes" if runs and all(r.valid for r in runs) else "NO",
            ]
        )
    return rows


def print_table(title: str, header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows, strict=True)]
    print(f"\n## {title}\n")
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for row in rows:
        print("| " + " | ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=5, help="seeds per paper example")
    parser.add_argument(
        "--reference-seeds", type=int, default=20, help="seeds per reference-workspace task"
    )
    parser.add_argument("--quick", action="store_true", help="1 seed each, skip OMPL")
    args = parser.parse_args()
    seeds = 1 if args.quick else args.seeds
    reference_seeds = 2 if args.quick else args.reference_seeds

    names = [n for n in EXAMPLES if (ROOT / "examples" / f"{n}.yaml").exists()]
    print_table(
        "Translation (ours vs ltl2ba 1.1 states / transitions)",
        ["mission", "ours", "ltl2ba", "ms"],
        [translation_row(n, load_mission(ROOT / "examples" / f"{n}.yaml")) for n in names],
    )
    header = [
        "mission",
        "solved",
        "first lasso CPU s",
        "first cost",
        "cost after budget",
        "CPU s with budget",
        "ref first s",
        "ref cost",
        "valid",
    ]
    print_table(
        f"TL-RRT* on the reference workspace ({reference_seeds} seeds; cost = 0.2 prefix "
        "+ 0.8 suffix)",
        header,
        mission_rows(["tlrrt-gf3", "tlrrt-case1"], reference_seeds),
    )
    print_table(
        f"TL-RRT* on the paper's examples ({seeds} seeds)", header, mission_rows(names, seeds)
    )
    if not args.quick:
        try:
            import rrt_vs_ompl
        except ImportError as error:
            print(f"\nOMPL comparison skipped: {error}")
        else:
            rrt_vs_ompl.main()


if __name__ == "__main__":
    main()
