"""Agent steps per second of every robot model, single env, one core, side by side.

Each robot runs random actions in a cluttered world (100 obstacles: half boxes, half balls, in a
20 m square or a 20 x 20 x 5 m box; the racecar also with 50 boxes, the issue's reference
setting) with ``collided()`` read after every step; on a collision it is reset to a random free
point, and resets count in the time. Run as ``OMP_NUM_THREADS=1 python bench/robots.py``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Run as a script, bench/ comes first on sys.path and bench/planner.py would shadow the package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from envs.robots import Robot, make_robot
from planner.geometry.shapes import Ball, Box, Shape
from planner.geometry.world import World


@dataclass(frozen=True)
class Case:
    """One benchmark row: a model in a world with ``obstacles`` shapes of the given kinds."""

    model: str
    dim: int
    obstacles: int
    kinds: str
    steps: int


CASES = (
    Case("unicycle", 2, 100, "boxes+balls", 100_000),
    Case("point", 2, 100, "boxes+balls", 100_000),
    Case("point", 3, 100, "boxes+balls", 100_000),
    Case("quadrotor", 3, 100, "boxes+balls", 10_000),
    Case("racecar", 2, 50, "boxes", 6_000),
    Case("racecar", 2, 100, "boxes+balls", 6_000),
)
RADIUS = 0.1


def cluttered_world(dim: int, n: int, kinds: str, seed: int) -> World:
    """A world with ``n`` random obstacles of side/diameter 0.4-1 m."""
    rng = np.random.default_rng(seed)
    extent = np.array([20.0, 20.0, 5.0][:dim])
    bounds = np.stack([np.zeros(dim), extent], axis=1)
    shapes: list[Shape] = []
    for i in range(n):
        size = rng.uniform(0.2, 0.5)
        center = rng.uniform(size, extent - size)
        if kinds == "boxes" or i % 2 == 0:
            shapes.append(Box(center - size, center + size))
        else:
            shapes.append(Ball(center, size))
    return World(bounds, shapes, {})


def run(case: Case, seed: int) -> tuple[float, Robot, int]:
    """Steps per second of ``case``, the robot (closed), and how many collisions it had."""
    world = cluttered_world(case.dim, case.obstacles, case.kinds, seed)
    robot = make_robot(case.model, world, RADIUS)
    rng = np.random.default_rng(seed)
    starts = world.sample_free(rng, 1000, RADIUS + 0.3)
    actions = rng.uniform(-1.0, 1.0, size=(case.steps, robot.action_dim))
    robot.reset(starts[0], rng)
    collisions = 0
    try:
        begin = time.perf_counter()
        for action in actions:
            robot.step(action)
            if robot.collided():
                collisions += 1
                robot.reset(starts[collisions % len(starts)], rng)
        elapsed = time.perf_counter() - begin
    finally:
        robot.close()
    return case.steps / elapsed, robot, collisions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0, help="multiply every step count")
    args = parser.parse_args()
    header = (
        f"{'model':<10} {'dim':>3} {'obstacles':>16} {'dt [s]':>7} {'substeps':>8} "
        f"{'steps':>7} {'collisions':>10} {'agent steps/s':>14} {'x real time':>11}"
    )
    print(header)
    print("-" * len(header))
    for case in CASES:
        steps = max(100, int(case.steps * args.scale))
        scaled = Case(case.model, case.dim, case.obstacles, case.kinds, steps)
        rate, robot, collisions = run(scaled, args.seed)
        substeps = getattr(robot.params, "substeps", 1)
        obstacles = f"{case.obstacles} {case.kinds}"
        print(
            f"{case.model:<10} {case.dim:>3} {obstacles:>16} {robot.dt:>7.3f} {substeps:>8} "
            f"{steps:>7} {collisions:>10} {rate:>14,.0f} {rate * robot.dt:>11,.0f}"
        )


if __name__ == "__main__":
    main()
