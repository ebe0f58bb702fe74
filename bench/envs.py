"""Agent steps per second of the navigation env against the bare robot dynamics, one core.

For each robot in a cluttered world (100 obstacles, half boxes and half balls, in a 20 m square
or a 20 x 20 x 5 m box; the racecar with 50 boxes, PyBullet being the slow part) and a guide
planned through it with RRT*, the same seeded random actions (forward-biased) drive:

* ``bare``: the robot alone (``step``, ``observation``, ``collided``; reset to the start on a
  crash), the dynamics a plain Gymnasium wrapper would cost;
* ``env rrt``: ``NavEnv`` with the default ``rrt`` reward and ``"guided"`` observation;
* ``env rays``: the same with 8 rays;
* ``batch(8)``: eight ``env rrt`` envs in a stable-baselines3 ``DummyVecEnv`` (what training
  steps), agent steps per second summed over the envs. Every env is stepped from Python one
  after the other, so this is the single-env rate minus the vector wrapper's cost, not a
  parallel speed-up (``SubprocVecEnv`` would spread envs over cores; the machine has two).

``overhead`` is the extra time per step of ``env rrt`` over ``bare`` (observation layout,
progress, reward, Gymnasium API); ``reward`` is the part of it spent in the progress tracker,
the goal test and the reward itself, replayed on the positions of the ``env rrt`` run, as a
share of the bare step. Runs are interleaved and the best of ``REPEATS`` is kept, so the
figures of one row are measured side by side.
Run as ``.venv/bin/python bench/envs.py [--quick] [--only MODEL]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
# Run as a script, bench/ comes first on sys.path and bench/envs.py would shadow the package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stable_baselines3.common.vec_env import DummyVecEnv

from envs.factory import make_env
from envs.nav_env import NavEnv
from envs.rewards import ScaledReward
from envs.robots import Robot, make_robot
from envs.spec import RobotSpec
from planner.decompose import SubTask
from planner.geometry.region_test import RegionTest
from planner.geometry.shapes import Ball, Box, Shape
from planner.geometry.world import World
from planner.guidance import ProgressTracker
from planner.search.rrt_star import RRTStar

RADIUS = 0.1
REPEATS = 3
BATCH = 8


@dataclass(frozen=True)
class Case:
    """One benchmark row."""

    model: str
    dim: int
    obstacles: int
    kinds: str
    steps: int


CASES = (
    Case("unicycle", 2, 100, "boxes+balls", 60_000),
    Case("point", 2, 100, "boxes+balls", 60_000),
    Case("point", 3, 100, "boxes+balls", 60_000),
    Case("quadrotor", 3, 100, "boxes+balls", 6_000),
    Case("racecar", 2, 50, "boxes", 3_000),
)


@dataclass(frozen=True)
class _Prebuilt:
    """A world section that hands back an already built world."""

    world: World

    def build(self, keep_clear: Sequence[np.ndarray] = ()) -> World:
        return self.world


@dataclass(frozen=True)
class _Mission:
    """The two sections ``make_env`` reads."""

    world: _Prebuilt
    robot: RobotSpec


def cluttered_world(dim: int, n: int, kinds: str, seed: int) -> tuple[World, np.ndarray]:
    """``n`` random obstacles of side/diameter 0.4-1 m, a goal region, and an RRT* guide to it
    from a far corner (``(k, dim)`` waypoints)."""
    rng = np.random.default_rng(seed)
    extent = np.array([20.0, 20.0, 5.0][:dim])
    start, goal = np.full(dim, 1.5), extent - 1.5
    if dim == 3:
        start[2] = goal[2] = 2.5
    shapes: list[Shape] = []
    while len(shapes) < n:
        size = rng.uniform(0.2, 0.5)
        center = rng.uniform(size, extent - size)
        if min(np.linalg.norm(center - start), np.linalg.norm(center - goal)) < 2.0:
            continue
        shapes.append(
            Box(center - size, center + size)
            if kinds == "boxes" or len(shapes) % 2 == 0
            else Ball(center, size)
        )
    bounds = np.stack([np.zeros(dim), extent], axis=1)
    world = World(bounds, shapes, {"goal": Ball(goal, 1.0)})
    tree = RRTStar(world, start, "goal", 1.0, RADIUS + 0.2, np.random.default_rng(seed))
    result = tree.run(4000)
    if result.path is None:
        raise RuntimeError("no guide found; try another seed")
    return world, np.asarray(result.path)


def actions(n: int, dim: int, seed: int) -> np.ndarray:
    """Seeded random actions in [-1, 1]^dim, the first component forward-biased."""
    a = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, dim)).astype(np.float32)
    a[:, 0] = np.abs(a[:, 0])
    return a


def bare_rate(robot: Robot, start: np.ndarray, acts: np.ndarray) -> float:
    rng = np.random.default_rng(0)
    robot.reset(start, rng, 0.0)
    t0 = time.perf_counter()
    for a in acts:
        robot.step(a)
        robot.observation()
        if robot.collided():
            robot.reset(start, rng, 0.0)
    return len(acts) / (time.perf_counter() - t0)


def env_rate(env: NavEnv, acts: np.ndarray, trace: list[list[float]] | None = None) -> float:
    env.reset(seed=0)
    t0 = time.perf_counter()
    for a in acts:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    rate = len(acts) / (time.perf_counter() - t0)
    if trace is not None:
        env.reset(seed=0)
        for a in acts:
            _, _, terminated, truncated, _ = env.step(a)
            trace.append(env.robot.position().tolist())
            if terminated or truncated:
                env.reset()
    return rate


def batch_rate(vec: DummyVecEnv, acts: np.ndarray) -> float:
    """Agent steps per second summed over the envs of ``vec`` (auto-reset on episode end)."""
    vec.seed(0)
    vec.reset()
    batch = acts[: len(acts) // vec.num_envs * vec.num_envs].reshape(
        -1, vec.num_envs, acts.shape[1]
    )
    t0 = time.perf_counter()
    for a in batch:
        vec.step(a)
    return batch.shape[0] * vec.num_envs / (time.perf_counter() - t0)


def reward_seconds(env: NavEnv, trace: list[list[float]]) -> float:
    """Time of the progress update, goal test and reward over the recorded positions."""
    leg = env.legs[0]
    tracker = ProgressTracker(leg.guide)
    goal = RegionTest(env.world.regions["goal"])
    mode = ScaledReward(env.options.rewards)
    togo = leg.guide.length
    t0 = time.perf_counter()
    for x in trace:
        improved, _, d = tracker.update_one(0, x)
        gain = 0.0
        if improved:
            gain, togo = togo - d, d
        if not goal.contains(x):
            mode.step_reward(improved, gain, x)
    return time.perf_counter() - t0


def run(case: Case, quick: bool) -> list[str]:
    world, path = cluttered_world(case.dim, case.obstacles, case.kinds, seed=1)
    steps = case.steps // 10 if quick else case.steps
    spec = RobotSpec(model=case.model, start=path[0].tolist(), radius=RADIUS)
    mission = _Mission(_Prebuilt(world), spec)
    sub = SubTask(0, "prefix", "goal", path[0], path, 0, 0)
    robot = make_robot(case.model, world, RADIUS)
    envs = [make_env(mission, sub, "rrt", world=world, rays=r) for r in (0, 8)]
    vec = DummyVecEnv([lambda: make_env(mission, sub, "rrt", world=world) for _ in range(BATCH)])
    try:
        acts = actions(steps, robot.action_dim, seed=2)
        trace: list[list[float]] = []
        bare = full = rays = batch = 0.0
        reward = float("inf")
        # Best of REPEATS interleaved runs: the machine is shared, and noise only slows runs.
        for k in range(REPEATS):
            bare = max(bare, bare_rate(robot, path[0], acts))
            full = max(full, env_rate(envs[0], acts, trace if k == 0 else None))
            rays = max(rays, env_rate(envs[1], acts))
            batch = max(batch, batch_rate(vec, acts))
            reward = min(reward, reward_seconds(envs[0], trace) / len(trace))
    finally:
        robot.close()
        for env in envs:
            env.close()
        vec.close()
    overhead = 100.0 * (bare / full - 1.0)
    share = 100.0 * reward * bare
    name = f"{case.model} {case.dim}D"
    world_text = f"{case.obstacles} {case.kinds}"
    return [
        name,
        world_text,
        f"{bare:,.0f}",
        f"{full:,.0f}",
        f"{rays:,.0f}",
        f"{batch:,.0f}",
        f"{overhead:.0f} %",
        f"{share:.0f} % ({reward * 1e6:.1f} us)",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a tenth of the steps")
    parser.add_argument("--only", help="run only this robot model")
    args = parser.parse_args()
    header = [
        "robot",
        "world",
        "bare /s",
        "env rrt /s",
        "env rays /s",
        f"batch({BATCH}) /s",
        "overhead",
        "reward",
    ]
    rows = [header]
    for case in CASES:
        if args.only and case.model != args.only:
            continue
        rows.append(run(case, args.quick))
        print(" | ".join(rows[-1]), file=sys.stderr, flush=True)
    widths = [max(len(r[k]) for r in rows) for k in range(len(header))]
    print(
        f"agent steps per second (batch: summed over {BATCH} envs stepped in turn), one core, "
        f"best of {REPEATS} interleaved runs (OMP_NUM_THREADS=1)"
    )
    for k, row in enumerate(rows):
        print("  ".join(v.rjust(w) for v, w in zip(row, widths, strict=True)))
        if k == 0:
            print("  ".join("-" * w for w in widths))


if __name__ == "__main__":
    main()
