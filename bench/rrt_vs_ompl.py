"""Our geometric RRT* against OMPL's RRT*: path cost at equal CPU time on one 2D world.

The world is 20 x 20 m with 50 random boxes; the robot (clearance 0.2 m) goes from the corner
(-9, -9) to a goal ball of radius 0.5 m around (9, 9). Both planners use steering range 1 m,
goal bias 0.05, rewiring radius ``min(1.1 (2 (1 + 1/d) mu / zeta_d)^(1/d) (log n / n)^(1/d), 1)``
and the same collision checker, our :class:`planner.geometry.world.World` (exact segment tests):

- ``ours``: :class:`planner.search.rrt_star.RRTStar`, which checks all candidate parents of a
  new node in one vectorised call;
- ``ompl``: OMPL's ``RRTstar`` (radius variant, ``setKNearest(False)``) with a Python
  ``MotionValidator`` calling ``World.segments_free`` once per motion and a state validity
  checker calling ``World.in_collision``;
- ``ompl-knn``: the same with OMPL's default k-nearest rewiring.

Budgets are CPU seconds of the planning loop (``time.process_time``); OMPL stops through a
termination condition that reads the same clock. OMPL's global seed can only be set before its
first sample, so every OMPL trial runs in a fresh interpreter. Every reported path is re-checked
with ``World.segments_free``. Run as ``python bench/rrt_vs_ompl.py [--seeds N] [--seconds S]``;
OMPL is the optional ``bench`` extra (``pip install ompl``): without it only our planner runs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

# Run as a script, bench/ comes first on sys.path and bench/planner.py would shadow the package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.geometry.shapes import Ball, Box, Shape
from planner.geometry.world import World
from planner.search.rrt_star import RRTStar

START = np.array([-9.0, -9.0])
GOAL = np.array([9.0, 9.0])
GOAL_RADIUS = 0.5
CLEARANCE = 0.2
ETA = 1.0
GOAL_BIAS = 0.05
OMPL_VARIANTS = ("ompl", "ompl-knn")


def build_world(seed: int = 0, count: int = 50) -> World:
    """20 x 20 world, ``count`` random boxes (0.6-2.2 m sides as in examples/), corners clear."""
    rng = np.random.default_rng(seed)
    keep = np.stack([START, GOAL])
    obstacles: list[Shape] = []
    while len(obstacles) < count:
        centre, size = rng.uniform(-10, 10, 2), rng.uniform(0.6, 2.2, 2)
        box = Box(centre - size / 2, centre + size / 2)
        if not box.contains(keep, 1.5).any():
            obstacles.append(box)
    return World([[-10.0, 10.0], [-10.0, 10.0]], obstacles, {"goal": Ball(GOAL, GOAL_RADIUS)})


def _path_valid(world: World, path: np.ndarray | None) -> bool:
    if path is None:
        return False
    free = world.segments_free(path[:-1], path[1:], CLEARANCE) if len(path) > 1 else [True]
    reached = bool(np.linalg.norm(path[-1] - GOAL) <= GOAL_RADIUS + 1e-9)
    return bool(np.all(free)) and reached and bool(np.allclose(path[0], START))


def run_ours(seed: int, cpu_seconds: float) -> dict[str, Any]:
    """One trial of our RRT* for ``cpu_seconds`` of planning."""
    world = build_world()
    planner = RRTStar(world, START, "goal", ETA, CLEARANCE, np.random.default_rng(seed), GOAL_BIAS)
    t0 = time.process_time()
    result = planner.run(10**9, cpu_seconds=cpu_seconds)
    cpu = time.process_time() - t0
    return {
        "planner": "ours",
        "seed": seed,
        "cost": result.cost,
        "iterations": planner.iterations,
        "nodes": result.nodes,
        "cpu": cpu,
        "valid": _path_valid(world, result.path),
    }


def run_ompl(seed: int, cpu_seconds: float, variant: str = "ompl") -> dict[str, Any]:
    """One OMPL trial in this process; call it in a fresh interpreter (seeding rule)."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_ERROR)
    ou.RNG.setSeed(seed + 1)  # OMPL rejects seed 0
    world = build_world()
    space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(-10.0)
    bounds.setHigh(10.0)
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda s: not world.in_collision([s[0], s[1]], CLEARANCE)[0])

    class WorldMotionValidator(ob.MotionValidator):
        """Exact segment test of our World, one Python call per motion."""

        def checkMotion(self, s1: Any, s2: Any, *rest: Any) -> bool:  # noqa: N802
            return world.segment_free([s1[0], s1[1]], [s2[0], s2[1]], CLEARANCE)

    validator = WorldMotionValidator(si)
    si.setMotionValidator(validator)
    si.setup()
    start, goal = space.allocState(), space.allocState()
    start[0], start[1] = float(START[0]), float(START[1])
    goal[0], goal[1] = float(GOAL[0]), float(GOAL[1])
    pdef = ob.ProblemDefinition(si)
    pdef.setStartAndGoalStates(start, goal, GOAL_RADIUS)
    pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    rrt = og.RRTstar(si)
    rrt.setRange(ETA)
    rrt.setGoalBias(GOAL_BIAS)
    rrt.setKNearest(variant == "ompl-knn")
    rrt.setProblemDefinition(pdef)
    rrt.setup()
    t0 = time.process_time()
    deadline = t0 + cpu_seconds
    rrt.solve(ob.PlannerTerminationCondition(lambda: time.process_time() >= deadline))
    cpu = time.process_time() - t0
    path: np.ndarray | None = None
    cost = float("inf")
    if pdef.hasExactSolution():
        solution = pdef.getSolutionPath()
        path = np.array(
            [
                [solution.getState(i)[0], solution.getState(i)[1]]
                for i in range(solution.getStateCount())
            ]
        )
        cost = float(solution.length())
    return {
        "planner": variant,
        "seed": seed,
        "cost": cost,
        "iterations": rrt.numIterations(),
        "nodes": None,
        "cpu": cpu,
        "valid": _path_valid(world, path),
    }


def _ompl_missing() -> str | None:
    try:
        import ompl  # noqa: F401
    except ImportError as error:
        return f"OMPL not installed ({error}); install the bench extra: pip install ompl"
    return None


def _ompl_trial(seed: int, cpu_seconds: float, variant: str) -> dict[str, Any]:
    """Run :func:`run_ompl` in a fresh interpreter and read its JSON answer."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, __file__, "--ompl-trial", json.dumps([seed, cpu_seconds, variant])],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def compare(
    seeds: int = 5, cpu_seconds: float = 2.0, variants: Sequence[str] = OMPL_VARIANTS
) -> list[dict[str, Any]]:
    """Run ours and every OMPL variant ``seeds`` times each; one dict per trial."""
    rows = [run_ours(seed, cpu_seconds) for seed in range(seeds)]
    if _ompl_missing() is None:
        rows += [_ompl_trial(seed, cpu_seconds, v) for v in variants for seed in range(seeds)]
    return rows


def _spread(values: Sequence[float], digits: int = 2) -> str:
    if not values:
        return "-"
    return (
        f"{statistics.median(values):.{digits}f} "
        f"({min(values):.{digits}f}-{max(values):.{digits}f})"
    )


def table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown table: per planner, median (min-max) cost, iterations, solved and valid counts."""
    lines = [
        "| planner | checker | cost, median (range) | iterations | solved | valid | cost / OMPL |",
        "|---|---|---|---|---|---|---|",
    ]
    names = list(dict.fromkeys(r["planner"] for r in rows))
    solved = {
        n: [r["cost"] for r in rows if r["planner"] == n and r["cost"] < float("inf")]
        for n in names
    }
    ref = statistics.median(solved["ompl"]) if solved.get("ompl") else None
    checkers = {
        "ours": "World, batched per node",
        "ompl": "World, one call per motion",
        "ompl-knn": "World, one call per motion",
    }
    for n in names:
        mine = [r for r in rows if r["planner"] == n]
        ratio = f"{statistics.median(solved[n]) / ref:.3f}" if ref and solved[n] else "-"
        lines.append(
            f"| {n} | {checkers.get(n, '?')} | {_spread(solved[n])} | "
            f"{_spread([float(r['iterations']) for r in mine], 0)} | {len(solved[n])}/{len(mine)} "
            f"| {sum(bool(r['valid']) for r in mine)}/{len(mine)} | {ratio} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """Print the comparison table (``argv`` None: defaults, for callers such as bench/planner)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument(
        "--seconds",
        type=float,
        nargs="+",
        default=[0.5, 2.0],
        help="CPU seconds per trial; one table per budget",
    )
    parser.add_argument("--ompl-trial", help=argparse.SUPPRESS)
    args = parser.parse_args([] if argv is None else argv)
    if args.ompl_trial:
        seed, seconds, variant = json.loads(args.ompl_trial)
        print(json.dumps(run_ompl(int(seed), float(seconds), str(variant))), flush=True)
        os._exit(0)  # skip interpreter teardown: nanobind reports OMPL's Python-held cycles
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    missing = _ompl_missing()
    if missing:
        print(f"OMPL comparison skipped: {missing}")
    bound = np.linalg.norm(GOAL - START) - GOAL_RADIUS
    for seconds in args.seconds:
        rows = compare(args.seeds, seconds)
        print(
            f"\nRRT* path cost at equal CPU time ({seconds:g} s per trial, {args.seeds} seeds; "
            f"straight-line lower bound {bound:.2f})"
        )
        print(table(rows))


if __name__ == "__main__":
    main(sys.argv[1:])
