"""The stall window against the robot's own controller on generated worlds (issue 18).

Training ends an episode that reaches no new r-ball for a while (``STALL_ENV_DEFAULTS``). A
window shorter than the time a good driver needs between two balls ends good episodes as
failures. For each robot and each generated mission of ``bench/generality.py`` (report seeds,
as there), every sub-task gets ``--episodes`` zero-action episodes (the robot's feed-forward
controller alone, from its real starts with the evaluation's start noise, no stall) and each
records the longest run of steps without a new ball before it ends. The table prints, per
robot and window, how many of the controller's successful episodes that window would have
cut: the default's fixed 30 steps, and ``--spacings`` (``stall_spacings``, 4 unless given:
``envs.factory.stall_window``).

Run ``.venv/bin/python bench/stall_window.py --robots point quadrotor --missions 10`` (a few
minutes a robot; plans are kept in ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "bench"))  # after the packages: bench/envs.py

import numpy as np  # noqa: E402
from generality import ROBOTS, mission  # noqa: E402

from envs.factory import stall_window  # noqa: E402
from envs.nav_env import NavEnv  # noqa: E402
from workers.env_defaults import STALL_ENV_DEFAULTS  # noqa: E402
from workers.mission import MissionError, parse_mission  # noqa: E402
from workers.run import stored_or_new_plan  # noqa: E402
from workers.training import subtask_env  # noqa: E402

FIXED = int(STALL_ENV_DEFAULTS["stall_steps"])
"""The default fixed window (steps)."""


@dataclass
class Episode:
    success: bool
    longest: int
    """Most steps without a new ball at any step that did not end the episode."""


@dataclass
class SubtaskRecord:
    episodes: list[Episode]
    derived: int
    """The window ``stall_spacings`` gives this sub-task (steps)."""


def controller_episodes(env: NavEnv, episodes: int, seed: int) -> list[Episode]:
    """``episodes`` zero-action episodes of ``env`` and how long each went without a new ball."""
    out = []
    action = np.zeros(env.robot.action_dim, dtype=np.float32)
    env.reset(seed=seed)
    for _ in range(episodes):
        longest = 0
        while True:
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
            longest = max(longest, env.steps_without_progress)
        out.append(Episode(bool(info["is_success"]), longest))
        env.reset()
    return out


def mission_records(
    robot: str, index: int, episodes: int, spacings: float, out: Path
) -> list[SubtaskRecord]:
    """The records of every sub-task of generated mission ``index`` of ``robot`` (none: no
    plan)."""
    spec = parse_mission(mission(robot, index))
    try:
        plan = stored_or_new_plan(spec, out / f"{robot}-{index}")
    except MissionError as error:
        print(f"{robot} {index}: no plan ({error})", flush=True)
        return []
    records = []
    for k in range(len(plan.subtasks)):
        env = subtask_env(spec, plan, spec.training, k, evaluation=True)
        try:
            trained = dataclasses.replace(env.options, stall_steps=0, stall_spacings=spacings)
            derived = stall_window(env.legs, env.robot, trained)
            records.append(SubtaskRecord(controller_episodes(env, episodes, seed=k), derived))
        finally:
            env.close()
    return records


def cut(records: list[SubtaskRecord], window: int | None) -> tuple[int, int]:
    """(successful episodes, of them cut by ``window``; None: each sub-task's derived one)."""
    wins = cuts = 0
    for record in records:
        limit = record.derived if window is None else window
        for episode in record.episodes:
            if episode.success:
                wins += 1
                cuts += episode.longest >= limit
    return wins, cuts


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    p.add_argument("--missions", type=int, default=10)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--spacings", type=float, default=4.0, help="stall_spacings to compare")
    p.add_argument("--out", type=Path, default=ROOT / "var" / "bench" / "stall_window")
    args = p.parse_args(argv)
    rows = []
    for robot in args.robots:
        records: list[SubtaskRecord] = []
        for index in range(args.missions):
            records.extend(mission_records(robot, index, args.episodes, args.spacings, args.out))
        wins, fixed_cuts = cut(records, FIXED)
        _, derived_cuts = cut(records, None)
        windows = [r.derived for r in records]
        rows.append(
            f"| {robot} | {len(records)} | {wins} | {fixed_cuts} ({_share(fixed_cuts, wins)}) "
            f"| {derived_cuts} ({_share(derived_cuts, wins)}) | {min(windows)}-"
            f"{statistics.median(windows):.0f}-{max(windows)} |"
        )
        print(rows[-1], flush=True)
    print(
        f"\n{args.missions} generated missions per robot (report seeds), {args.episodes} "
        "controller episodes per sub-task\n\n| robot | sub-tasks | successful episodes | cut "
        f"by {FIXED} steps (default) | cut by stall_spacings {args.spacings:g} | that window, "
        "steps (min-median-max) |\n|---|---|---|---|---|---|"
    )
    print("\n".join(rows))


def _share(part: int, whole: int) -> str:
    return f"{100 * part / whole:.0f} %" if whole else "-"


if __name__ == "__main__":
    main()
