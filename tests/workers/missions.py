"""The tiny mission the worker tests train on for real (tiny budgets, real code paths)."""

from __future__ import annotations

import copy
from typing import Any

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
    data["training"].update(training)
    return parse_mission(data)
