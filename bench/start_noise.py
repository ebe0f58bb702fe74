"""How much of a mission's failure rate its start spread causes: whole-mission rollouts of
trained bundles and of the zero action (the control) at several start spreads (issue 19: the
evaluation's start noise; issue 17: the racecar's ceiling).

Each bundle's concatenated policy is rolled out on its own mission and plan with the reported
rollouts' seeds (``training.seed + EVALUATION_SEED``) and its recorded evaluation options, the
start spread (``start_noise`` in metres, ``heading_noise`` in radians, both uniform) replaced
by each ``--spreads`` pair. The zero action runs on the first bundle's mission in the same env.
At the bundle's own spread the rollouts start where the reported ones did (printed beside); a
borderline rollout may still end otherwise, as the policy's batched forward pass differs in the
last bits when the reported rollouts were shared over processes.

Run ``.venv/bin/python bench/start_noise.py RUN/bundle.zip ... --spreads 0,0 0.1,0.2 0.2,0.4``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from envs.mission_env import MissionEnv  # noqa: E402
from workers.bundle_reader import ConcatenatedPolicy  # noqa: E402
from workers.control import zero_action  # noqa: E402
from workers.evaluation import Act, MissionEvaluation, rollout_mission, stage_policies  # noqa: E402
from workers.policy_act import deterministic_act  # noqa: E402
from workers.run import EVALUATION_SEED  # noqa: E402


def spread(text: str) -> tuple[float, float]:
    """``"0.2,0.4"`` -> (start_noise, heading_noise)."""
    position, heading = (float(part) for part in text.split(","))
    return position, heading


def rollouts(
    policy: ConcatenatedPolicy,
    noise: tuple[float, float],
    episodes: int,
    lanes: int | None,
    control: bool = False,
) -> MissionEvaluation:
    """``policy`` (``control``: the zero action) rolled out on ``policy``'s mission with the
    start spread ``noise``."""
    options = dataclasses.replace(policy.options(), start_noise=noise[0], heading_noise=noise[1])
    count = lanes or policy.mission.training.eval_lanes
    envs = [MissionEnv(policy.mission, policy.plan, options, policy.cycles) for _ in range(count)]
    seed = policy.mission.training.seed + EVALUATION_SEED
    if control:
        act: Act = zero_action(envs[0].robot.action_dim)
    else:
        act = stage_policies(envs[0].sequence, [deterministic_act(p) for p in policy.policies])
    try:
        return rollout_mission(act, envs, episodes, seed=seed)
    finally:
        for env in envs:
            env.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bundles", type=Path, nargs="+")
    parser.add_argument("--spreads", type=spread, nargs="+", default=[(0, 0), (0.2, 0.4)])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--lanes", type=int, help="default: the mission's eval_lanes")
    args = parser.parse_args(argv)
    policies = [ConcatenatedPolicy.load(path) for path in args.bundles]
    first = policies[0]
    print(
        f"{first.mission.name}: {args.episodes} rollouts per cell; recorded spread "
        f"{first.options().start_noise} m / {first.options().heading_noise} rad\n"
    )
    header = " | ".join(f"{m} m / {h} rad" for m, h in args.spreads)
    print(f"| policy | reported | {header} |")
    print("|---|---|" + "---|" * len(args.spreads))
    rows: list[tuple[str, ConcatenatedPolicy, bool, str]] = [
        ("zero action (control)", first, True, "-")
    ]
    for path, policy in zip(args.bundles, policies, strict=True):
        reported = policy.manifest.mission_evaluation
        shown = "-" if reported is None else f"{100 * reported['success_rate']:.0f} %"
        rows.append((str(path), policy, False, shown))
    for name, policy, control, shown in rows:
        cells = []
        for noise in args.spreads:
            result = rollouts(policy, noise, args.episodes, args.lanes, control)
            cells.append(f"{100 * result.success_rate:.0f} %")
        print(f"| {name} | {shown} | " + " | ".join(cells) + " |", flush=True)
    for policy in policies:
        policy.close()


if __name__ == "__main__":
    main()
