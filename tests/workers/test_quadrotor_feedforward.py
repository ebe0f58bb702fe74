"""The quadrotor's feed-forward and default planner margin carry it around a tower's corners.

A 40 x 40 m world (r-balls of 1.4 m) with one long tower between the start and the goal: the
guide turns two right-angled corners of it. The carrot two balls ahead, which the quadrotor
followed before, cut those corners into the tower on every start; pursuit of the guide half a
second ahead, on a guide planned 0.3 m off the tower, does not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from workers.evaluation import evaluate_subtask
from workers.mission import parse_mission
from workers.run import stored_or_new_plan
from workers.training import subtask_env

EPISODES = 4


def around_the_tower(**planner: Any) -> dict[str, Any]:
    return {
        "name": "tower",
        "task": "[]!obstacle && <>g1",
        "robot": {"model": "quadrotor", "start": [3.0, 4.0, 2.0], "radius": 0.2},
        "planner": {"seed": 0, **planner},
        "world": {
            "bounds": [[0, 40], [0, 40], [0, 4]],
            "obstacles": [{"box": {"min": [6, 0, 0], "max": [34, 30, 4]}}],
            "regions": {"g1": {"ball": {"center": [37.0, 4.0, 2.0], "radius": 0.5}}},
        },
    }


def zero_action_outcome(document: dict[str, Any], folder: Path) -> tuple[float, float, float]:
    """Clearance of the plan, success and collision rates of the zero action."""
    mission = parse_mission(document)
    plan = stored_or_new_plan(mission, folder)
    env = subtask_env(mission, plan, mission.training, 0, evaluation=True)
    try:
        zeros = np.zeros(env.robot.action_dim, dtype=np.float32)
        outcome = evaluate_subtask(lambda _o: zeros, env, EPISODES, seed=0)
    finally:
        env.close()
    return plan.clearance, outcome.success_rate, outcome.collision_rate


def test_the_zero_action_flies_around_the_tower_on_the_default_margin(tmp_path: Path) -> None:
    clearance, success, _ = zero_action_outcome(around_the_tower(), tmp_path / "default")
    assert clearance == pytest.approx(0.5)  # radius 0.2 + the quadrotor's margin 0.3
    assert success == 1.0


def test_a_guide_that_grazes_the_tower_is_not_held(tmp_path: Path) -> None:
    clearance, success, collisions = zero_action_outcome(around_the_tower(margin=0), tmp_path)
    assert clearance == pytest.approx(0.2)
    assert (success, collisions) == (0.0, 1.0)
