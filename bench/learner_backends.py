"""The learner's rate under each ``training.backend`` (issue 17, item 3): SAC of stable-baselines3
as jobs run it (lean, ``workers.lean_learner``) and in SB3's own loop, against SAC of SBX (JAX),
each with one env per learner or several (``--envs``), side by side in one run.

Both learn on the NavEnv of a mission's sub-task 0 with its training options and the same
hyperparameters (the mission's, over the defaults: network, batch, ``train_freq``), built as a
training job builds them (``workers.agents``; torch and XLA on ``torch_threads`` threads each;
XLA's pool runs beside the Python thread that drives it: the CPU rate below the wall rate shows
what that overlap adds). Each run
first learns 1,000 steps (SBX compiles its update then; both fill past ``learning_starts``),
then ``--steps`` timed steps; the variants alternate, best of ``--repeats``. With ``n`` envs
(``training.n_envs``: a ``DummyVecEnv`` of ``n`` copies, stepped in turn in one process) the
learner makes as many gradient steps per env step as with one: the envs share the policy's
forward pass and SB3's loop, nothing else. Beside them, the env alone under
seeded random actions: what is left of a training step is the learner's (its update, its
action, the replay buffer and SB3's loop).

Run ``.venv/bin/python bench/learner_backends.py [--missions NAME ...]`` (names of examples or
of ``bench/missions`` files; about a minute per mission).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.overhead import env_step_seconds  # noqa: E402
from bench.train_speed import mission_path  # noqa: E402
from workers.mission import load_mission  # noqa: E402
from workers.run import stored_or_new_plan  # noqa: E402

LEARNERS = {"sb3, SB3's loop": ("sb3", False), "sb3": ("sb3", True), "sbx": ("sbx", False)}
"""Row name: ``training.backend`` and whether the model is made lean as a job makes it."""
WARM_UP = 1_000


def rates(name: str, steps: int, repeats: int, env_counts: list[int]) -> str:
    """One table row per backend and number of envs: env steps per wall and per CPU second, ms
    per step."""
    import numpy as np
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    from workers.agents import algorithm_class, hyperparameters
    from workers.lean_learner import make_lean
    from workers.training import subtask_env
    from workers.training_spec import TrainingSpec

    mission = load_mission(mission_path(name))
    out = Path(os.environ.get("TMPDIR", "/tmp")) / "ltlnav-bench-backends" / name
    plan = stored_or_new_plan(mission, out)
    torch.set_num_threads(mission.training.torch_threads)
    variants = [(learner, n) for learner in LEARNERS for n in env_counts]
    best = {v: (0.0, 0.0) for v in variants}
    for _ in range(repeats):
        for learner, n in variants:
            backend, lean = LEARNERS[learner]
            fields = {**mission.training.model_dump(), "backend": backend, "n_envs": n}
            training = TrainingSpec.model_validate(fields)
            env = DummyVecEnv([partial(subtask_env, mission, plan, training, 0)] * n)
            shape = env.action_space.shape
            assert shape is not None
            params = hyperparameters(training, int(np.prod(shape)))
            model = algorithm_class(training)("MlpPolicy", env, seed=0, device="cpu", **params)
            if lean:
                make_lean(model)
            model.learn(WARM_UP)
            wall, cpu = time.perf_counter(), time.process_time()
            model.learn(steps, reset_num_timesteps=False)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            old_wall, old_cpu = best[learner, n]
            best[learner, n] = (max(old_wall, steps / wall), max(old_cpu, steps / cpu))
            env.close()
    alone = env_step_seconds(subtask_env(mission, plan, mission.training, 0), steps)
    rows = []
    first = best["sb3, SB3's loop", env_counts[0]][0]
    for learner, n in variants:
        per_wall, per_cpu = best[learner, n]
        update_ms = 1e3 * (1 / per_cpu - alone)
        rows.append(
            f"| {name} | {learner} | {n} | {per_wall:.0f} | {per_cpu:.0f} | {1e3 / per_cpu:.2f} "
            f"| {1e3 * alone:.2f} | {update_ms:.2f} | {per_wall / first:.2f} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--missions", nargs="*", default=["car-phi2-fin", "racecar-dense-forest-15"]
    )
    parser.add_argument("--steps", type=int, default=4_000, help="timed SAC steps per run")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--envs", nargs="*", type=int, default=[1], help="envs per learner to compare (n_envs)"
    )
    args = parser.parse_args(argv)
    print(
        f"SAC on each mission's sub-task 0, {args.steps} timed env steps, best of {args.repeats}, "
        f"gradient steps per env step and network as the mission trains\n\n"
        "| mission | backend | envs | steps / wall s | steps / CPU s | ms per step | env alone, ms "
        f"| learner, ms | wall rate vs SB3's loop with {args.envs[0]} |\n"
        "|---|---|---|---|---|---|---|---|---|"
    )
    for name in args.missions:
        print(rates(name, args.steps, args.repeats, args.envs), flush=True)


if __name__ == "__main__":
    main()
