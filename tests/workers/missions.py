"""The tiny mission the worker tests train on for real (tiny budgets, real code paths)."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

from workers.hooks import CurvePoint, TrainingHooks
from workers.mission import MissionSpec, parse_mission

TINY: dict[str, Any] = {
    "name": "tiny-gf2",
    "task": "[]!obstacle && []<>a && []<>b",
    "robot": {"model": "point", "start": [0.5, 0.5], "radius": 0.05},
    "planner": {"seed": 1, "refine_iterations": 300},
    "world": {
        "bounds": [[0, 4], [0, 4]],
        "obstacles": [{"box": {"min": [2.6, 2.6], "max": [3.4, 3.4]}}],
        "regions": {
            "a": {"ball": {"center": [3.4, 0.6], "radius": 0.3}},
            "b": {"box": {"min": [0.2, 3.2], "max": [0.8, 3.8]}},
        },
    },
    "training": {
        "n_timesteps": 200,
        "eval_freq": 100,
        "eval_episodes": 1,
        "final_eval_episodes": 2,
        "mission_episodes": 2,
        "handover_steps": 200,
        # the plateau stop and the pick are tested on their own (test_training,
        # test_policy_pick): with one-episode evaluations they would end most jobs here early
        "plateau_evals": None,
        "pick_candidates": None,
        # these tests train an agent: without the point robot's default feed-forward, which
        # meets such short sub-tasks at step 0
        "env": {"guide_feedforward": None},
        "hyperparams": {
            "policy_kwargs": {"net_arch": [8]},
            "learning_starts": 50,
            "batch_size": 16,
            "buffer_size": 5000,
        },
    },
}
"""A 4 x 4 m world, a point robot and GF a & GF b: four short sub-tasks, net_arch [8]."""


def tiny_mission(**training: Any) -> MissionSpec:
    data = copy.deepcopy(TINY)
    env = {**data["training"]["env"], **training.pop("env", {})}
    data["training"].update(training, env=env)
    return parse_mission(data)


class Recorder(TrainingHooks):
    """Hooks that record what a job told them and stop when ``stop()`` says so."""

    def __init__(self, stop: Callable[[], bool] | None = None) -> None:
        self.stop = stop
        self.progressed: list[tuple[int, float | None, int]] = []
        self.points: list[CurvePoint] = []
        self.saved: list[tuple[int, Path]] = []
        self.resumes: list[int] = []

    def resumed(self, steps: int) -> None:
        self.resumes.append(steps)

    def progress(self, steps: int, success_rate: float | None, total: int) -> None:
        self.progressed.append((steps, success_rate, total))

    def curve_point(self, point: CurvePoint) -> None:
        self.points.append(point)

    def checkpoint(self, steps: int, path: Path) -> None:
        self.saved.append((steps, path))

    def should_stop(self) -> bool:
        return self.stop is not None and self.stop()
