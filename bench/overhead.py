"""What the env and reward cost against raw stable-baselines3 (issue 4: <= 10 % of the
training time).

SAC with the training network (one torch thread) trains on the bare robot dynamics (no world,
no guide, no reward) and on the ``NavEnv`` of the mission's sub-task 0 with the mission's
training options (``rrt``), interleaved, best of three; the ratio of their steps per CPU
second. Beside it, each env alone under the same seeded random actions: the NavEnv's extra CPU
time per step as a share of a training step, the steadier figure (SAC's rate moves by several
percent from one run to the next on a shared machine).

Run ``.venv/bin/python bench/overhead.py [--mission NAME]`` (an example's name; a few minutes).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from workers.mission import load_mission  # noqa: E402
from workers.run import stored_or_new_plan  # noqa: E402


def overhead(steps: int, repeats: int, mission_name: str) -> str:
    """SAC steps per CPU second (one process, one torch thread) on the bare dynamics against
    the NavEnv of the mission's sub-task 0 with its training options, interleaved."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import SAC

    from envs.robots import make_robot
    from workers.agents import hyperparameters
    from workers.training import subtask_env

    torch.set_num_threads(1)
    mission = load_mission(ROOT / "examples" / f"{mission_name}.yaml")
    out = Path(os.environ.get("TMPDIR", "/tmp")) / "ltlnav-bench-overhead" / mission_name
    plan = stored_or_new_plan(mission, out)
    training = mission.training

    class Bare(gym.Env[np.ndarray, np.ndarray]):
        """The robot's dynamics alone, observation padded to the NavEnv's size."""

        def __init__(self, size: int) -> None:
            world = mission.build_world()  # the robot's own collision test is part of it
            self.robot = make_robot(mission.robot.model, world, mission.robot.radius)
            self.start = np.asarray(plan.start, dtype=float)
            self.rng = np.random.default_rng(0)
            n = self.robot.action_dim
            self.action_space = gym.spaces.Box(-1.0, 1.0, (n,), np.float32)
            self.observation_space = gym.spaces.Box(-np.inf, np.inf, (size,), np.float32)
            self.size, self.t = size, 0

        def _obs(self) -> np.ndarray:
            o = np.zeros(self.size, np.float32)
            raw = np.asarray(self.robot.observation(), np.float32)[: self.size]
            o[: raw.size] = raw
            return o

        def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
            super().reset(seed=seed)
            self.robot.reset(self.start, self.rng)
            self.t = 0
            return self._obs(), {}

        def step(self, action: np.ndarray) -> Any:
            self.robot.step(action)
            self.t += 1
            return self._obs(), 0.0, False, self.t >= 400, {}

    nav = subtask_env(mission, plan, training, 0)
    bare = Bare(int(np.prod(nav.observation_space.shape or (0,))))
    params = hyperparameters(training, bare.robot.action_dim)
    rates: dict[str, float] = {"bare": 0.0, "env": 0.0}
    for _ in range(repeats):
        for name, env in (("bare", bare), ("env", nav)):
            model = SAC("MlpPolicy", env, seed=0, device="cpu", verbose=0, **params)
            t0 = time.process_time()  # CPU time: the machine is shared, wall time is noise
            model.learn(steps)
            rates[name] = max(rates[name], steps / (time.process_time() - t0))
    share = 100.0 * (1.0 - rates["env"] / rates["bare"])
    per_step = {name: env_step_seconds(env, steps) for name, env in (("bare", bare), ("env", nav))}
    extra = per_step["env"] - per_step["bare"]
    return (
        f"| env | SAC steps per CPU second (best of {repeats}, {steps} steps) "
        f"| env step alone, ms (random actions) |\n|---|---|---|\n"
        f"| bare {mission.robot.model} dynamics | {rates['bare']:.0f} "
        f"| {1e3 * per_step['bare']:.2f} |\n"
        f"| NavEnv {mission_name} sub-task 0 (rrt, training options) | {rates['env']:.0f} "
        f"| {1e3 * per_step['env']:.2f} |\n\n"
        f"env + reward share of the training time: {share:.1f} % from the SAC rates; "
        f"{100.0 * extra * rates['env']:.1f} % from the env steps alone "
        f"({1e3 * extra:.2f} ms more per step) (target <= 10 %)"
    )


def env_step_seconds(env: Any, steps: int) -> float:
    """CPU seconds per step (resets included) of ``env`` under seeded random actions."""
    env.action_space.seed(0)
    env.reset(seed=0)
    t0 = time.process_time()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    return (time.process_time() - t0) / steps


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mission", default="car-phi2-fin", help="an example's name")
    parser.add_argument("--steps", type=int, default=3000, help="SAC steps per run")
    args = parser.parse_args(argv)
    print(overhead(args.steps, 3, args.mission))


if __name__ == "__main__":
    main()
