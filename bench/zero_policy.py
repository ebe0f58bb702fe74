"""What a mission's env defaults achieve with no learning: the zero action on every sub-task.

The control experiment for action-shaping defaults (``guide_feedforward``, ``min_forward``): a
policy that always outputs zeros, evaluated like a trained one (``workers.control``:
``final_eval_episodes`` trials per sub-task from its real start, then ``mission_episodes``
whole-mission rollouts, at the reported figures' seeds). Whatever it reaches is owed to the
defaults, not to training.

Run ``.venv/bin/python bench/zero_policy.py examples/quad-phi1-inf.yaml`` (a few minutes); the
plan is made (or reused) in ``var/bench/zero_policy/<mission>/``, so variants given with
``--env '{"guide_feedforward": null}'`` (``training.env`` overrides) run on the same plan.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from workers.control import zero_control  # noqa: E402
from workers.mission import load_mission, parse_mission  # noqa: E402
from workers.run import stored_or_new_plan  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mission", type=Path)
    parser.add_argument("--out", type=Path, default=ROOT / "var" / "bench" / "zero_policy")
    parser.add_argument("--env", default="{}", help="training.env overrides, JSON")
    args = parser.parse_args(argv)
    mission = load_mission(args.mission)
    overrides = json.loads(args.env)
    if overrides:
        document = mission.model_dump(mode="json")
        document["training"]["env"].update(overrides)
        mission = parse_mission(document)
    training = mission.training
    plan = stored_or_new_plan(mission, args.out / mission.name)
    robot = mission.robot.model
    print(
        f"{mission.name} ({robot}), zero action; eval options: {training.eval_env_options(robot)}\n"
    )
    evaluation = zero_control(mission, plan)
    print("| sub-task | success | collisions | timeouts | mean steps to goal |")
    print("|---|---|---|---|---|")
    for k, ev in enumerate(evaluation.subtasks):
        steps = "-" if ev.mean_steps_to_goal is None else f"{ev.mean_steps_to_goal:.0f}"
        print(
            f"| {k} | {ev.success_rate:.1%} | {ev.collision_rate:.1%} | {ev.timeout_rate:.1%} "
            f"| {steps} |"
        )
    rollouts = evaluation.mission
    print(
        f"\nmission: {rollouts.success_rate:.1%} of {rollouts.episodes} rollouts; failures by "
        f"sub-task: {rollouts.failures}"
    )


if __name__ == "__main__":
    main()
