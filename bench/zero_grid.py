"""The zero action on generated tuning worlds: which sub-tasks the robot's controller holds alone.

The grid behind the controller and margin defaults (``bench/LEARNING.md``): for each generator
seed of ``bench/generality.py`` (tuning seeds only: ``TUNING_SEEDS``), the mission is planned
(with ``--margin`` when given, else the robot's default), and each sub-task gets ``--episodes``
zero-action episodes from its real starts. A sub-task is held at >= 90 % success; a world when
all its sub-tasks are. ``--env`` overrides ``training.env`` (JSON), so variants run on the same
plans (they are kept in ``--out``).

Run ``.venv/bin/python bench/zero_grid.py unicycle --seeds 0 20``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from generality import ROBOTS, TUNING_SEEDS, generate  # noqa: E402

from workers.control import zero_action  # noqa: E402
from workers.evaluation import evaluate_subtask  # noqa: E402
from workers.mission import MissionError, parse_mission  # noqa: E402
from workers.run import stored_or_new_plan  # noqa: E402
from workers.training import subtask_env  # noqa: E402

HELD = 0.9
"""Success rate from which a sub-task counts as held."""


def world_rates(
    robot: str, seed: int, margin: float | None, env: dict[str, object], episodes: int, out: Path
) -> list[float] | None:
    """Zero-action success rate of every sub-task of generator ``seed`` (None: no plan)."""
    doc = generate(robot, seed, seed)
    if margin is not None:
        doc["planner"]["margin"] = margin
    doc["training"] = {"env": env}
    try:
        return controller_rates(doc, episodes, out / f"{robot}-{seed}-margin-{margin}")
    except MissionError as error:
        print(f"seed {seed}: no plan ({error})", flush=True)
        return None


def controller_rates(doc: dict[str, Any], episodes: int, folder: Path) -> list[float]:
    """Zero-action success rate of every sub-task of the mission ``doc`` from its real starts,
    its plan kept in ``folder`` (``MissionError``: no plan)."""
    mission = parse_mission(doc)
    plan = stored_or_new_plan(mission, folder)
    rates = []
    for k in range(len(plan.subtasks)):
        lanes = [
            subtask_env(mission, plan, mission.training, k, evaluation=True)
            for _ in range(mission.training.eval_lanes)
        ]
        try:
            act = zero_action(lanes[0].robot.action_dim)
            rates.append(evaluate_subtask(act, lanes, episodes, seed=0).success_rate)
        finally:
            for env_ in lanes:
                env_.close()
    return rates


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("robot", choices=list(ROBOTS))
    p.add_argument("--seeds", nargs=2, type=int, default=[0, 20], help="first, end (exclusive)")
    p.add_argument("--margin", type=float, help="planner.margin (default: the robot's)")
    p.add_argument("--env", default="{}", help="training.env overrides, JSON")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", type=Path, default=ROOT / "var" / "bench" / "zero_grid")
    args = p.parse_args(argv)
    seeds = range(*args.seeds)
    if not set(seeds) <= set(TUNING_SEEDS):
        p.error(f"tune on TUNING_SEEDS ({TUNING_SEEDS}) only")
    env = json.loads(args.env)
    held = total = worlds = 0
    for seed in seeds:
        rates = world_rates(args.robot, seed, args.margin, env, args.episodes, args.out)
        if rates is None:
            continue
        held += sum(r >= HELD for r in rates)
        total += len(rates)
        worlds += all(r >= HELD for r in rates)
        print(f"seed {seed}: " + ", ".join(f"{100 * r:.0f} %" for r in rates), flush=True)
    print(
        f"{args.robot}, margin {args.margin}, env {env}: {held} of {total} sub-tasks held, "
        f"{worlds} of {len(seeds)} worlds"
    )


if __name__ == "__main__":
    main()
