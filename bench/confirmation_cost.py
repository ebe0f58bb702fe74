"""What a confirmation of the early stop costs run whole and stopped once the target is out of
reach (issue 17, item 3: cheaper evaluations), side by side on a finished training run.

A confirmation (``training.final_eval_episodes`` trials on a seed of its own) is run when a
periodic evaluation reaches ``training.target_success``; it now stops at the failure that puts
the target out of reach, which changes no decision (a confirmation that would pass never stops;
one that stops fails either way). For every sub-task policy of a finished ``ltlnav train`` run
(``model.zip`` and, in runs without the pick, the kept ``best_model.zip``) and the first
``--confirmations`` confirmation seeds from the mission's seed, both forms run in the job's
evaluation lanes, alternated, best of ``--repeats``: episodes run, success rate, CPU seconds.

Run ``.venv/bin/python bench/confirmation_cost.py FOLDER`` (a ``bench/train_speed.py`` row folder:
``mission.yaml`` and ``run/``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def confirmation_costs(folder: Path, confirmations: int, repeats: int, policies: list[str]) -> str:
    """One table row per policy and confirmation seed, and the total."""
    import torch

    from workers.agents import ALGORITHMS
    from workers.evaluation import evaluate_subtask, successes_needed
    from workers.mission import load_mission
    from workers.policy_act import deterministic_act
    from workers.run import stored_or_new_plan
    from workers.training import CONFIRMATION_SEED, subtask_env

    torch.set_num_threads(1)
    mission = load_mission(folder / "mission.yaml")
    training = mission.training
    plan = stored_or_new_plan(mission, folder / "run")
    episodes = training.final_eval_episodes
    needed = successes_needed(episodes, training.target_success)
    lines = [
        f"{episodes} trials, {needed} needed, {training.eval_lanes} lanes, best of {repeats}\n",
        "| policy | seed | whole: episodes, success, CPU s | stopped: episodes, success, CPU s "
        "| CPU ratio |",
        "|---|---|---|---|---|",
    ]
    totals = [0.0, 0.0]
    for k in range(len(plan.subtasks)):
        for name in policies:
            path = folder / "run" / f"subtask_{k}" / name
            if not path.is_file():
                continue
            act = deterministic_act(ALGORITHMS[training.algorithm].load(path, device="cpu").policy)
            envs = [
                subtask_env(mission, plan, training, k, True) for _ in range(training.eval_lanes)
            ]
            for n in range(confirmations):
                seed = training.seed + CONFIRMATION_SEED + n
                cells, best = [], []
                for required in (0, needed):
                    seconds = []
                    for _ in range(repeats):
                        started = time.process_time()
                        result = evaluate_subtask(act, envs, episodes, seed, required)
                        seconds.append(time.process_time() - started)
                    best.append(min(seconds))
                    cells.append(
                        f"{result.episodes}, {100 * result.success_rate:.1f} %, {best[-1]:.1f}"
                    )
                totals = [totals[0] + best[0], totals[1] + best[1]]
                lines.append(
                    f"| {k} {name} | {seed} | {cells[0]} | {cells[1]} | {best[1] / best[0]:.2f} |"
                )
            for env in envs:
                env.close()
    lines.append(
        f"| all | | {totals[0]:.1f} | {totals[1]:.1f} | {totals[1] / max(totals[0], 1e-9):.2f} |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a finished row: mission.yaml and run/")
    parser.add_argument("--confirmations", type=int, default=2, help="confirmation seeds each")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--policies", nargs="*", default=["model.zip", "best_model.zip"])
    args = parser.parse_args(argv)
    print(confirmation_costs(args.folder, args.confirmations, args.repeats, args.policies))


if __name__ == "__main__":
    main()
