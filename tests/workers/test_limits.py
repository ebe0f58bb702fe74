"""Admission limits: each hostile document refused quickly, naming field, value, limit and
setting; defaults admit the default mission and every example; the automaton limit at plan
time."""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import planner.plan
from planner.plan import MARGIN_SHARES, plan_mission
from planner.search.planner_spec import PlannerSpec
from planner.serialize import plan_to_dict
from service.settings import Settings
from tests.workers.missions import TINY
from workers.admission import admit, document_problems, load_admitted, mission_problems
from workers.limits import AdmissionLimits
from workers.mission import MissionError, MissionSpec, load_mission
from workers.run import stored_or_new_plan
from workers.training_spec import TrainingSpec

LIMITS = AdmissionLimits()
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def polygon(n: int) -> list[list[float]]:
    """A simple polygon of ``n`` vertices inside [1, 3]^2."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[2 + 0.8 * np.cos(angles), 2 + 0.8 * np.sin(angles)].round(3).tolist()


def with_(path: str, value: Any) -> dict[str, Any]:
    """The tiny mission with the default budget, ``path`` set to ``value``."""
    document = copy.deepcopy(TINY)
    document["training"].update(n_timesteps=150_000, eval_freq=5_000)
    *parents, last = path.split(".")
    target: Any = document
    for part in parents:
        target = target[int(part)] if part.isdigit() else target.setdefault(part, {})
    target[last] = value
    return document


HOSTILE: list[tuple[str, Any, str, str]] = [
    # (dotted path set, value, field in the problem, expected message)
    (
        "training.n_timesteps",
        10**12,
        "training.n_timesteps",
        "1000000000000 is over the limit 2000000 (LTLNAV_MAX_TIMESTEPS)",
    ),
    (
        "planner.time_limit",
        1e9,
        "planner.time_limit",
        "1000000000 is over the limit 600 (LTLNAV_MAX_PLANNER_SECONDS)",
    ),
    ("planner.max_iterations", 10**9, "planner.max_iterations", "LTLNAV_MAX_PLANNER_ITERATIONS"),
    ("planner.refine_iterations", 10**9, "planner.refine_iterations", "over the limit 1000000"),
    ("planner.refine_seconds", 1e6, "planner.refine_seconds", "LTLNAV_MAX_PLANNER_SECONDS"),
    (
        "training.hyperparams.buffer_size",
        10**10,
        "training.hyperparams.buffer_size",
        "10000000000 is over the limit 150000 (training.n_timesteps",
    ),
    (
        "training.hyperparams.policy_kwargs.net_arch",
        [100000, 100000],
        "training.hyperparams.policy_kwargs.net_arch",
        "a layer of 100000 units is over the limit 1024 (LTLNAV_MAX_NET_WIDTH)",
    ),
    (
        "training.hyperparams.policy_kwargs.net_arch",
        {"pi": [64], "qf": [64] * 50},
        "training.hyperparams.policy_kwargs.net_arch.qf",
        "has 50 layers, over the limit 8 (LTLNAV_MAX_NET_DEPTH)",
    ),
    (
        "training.checkpoint_freq",
        1,
        "training.checkpoint_freq",
        "1 is under the limit 150 (training.n_timesteps / LTLNAV_MAX_CHECKPOINTS",
    ),
    ("training.eval_freq", 10, "training.eval_freq", "10 is under the limit 150"),
    ("training.eval_episodes", 10**6, "training.eval_episodes", "LTLNAV_MAX_EPISODES"),
    ("training.final_eval_episodes", 10**6, "training.final_eval_episodes", "over the limit"),
    ("training.mission_episodes", 10**6, "training.mission_episodes", "LTLNAV_MAX_EPISODES"),
    ("training.handover_rounds", 1000, "training.handover_rounds", "LTLNAV_MAX_HANDOVER_ROUNDS"),
    ("training.handover_steps", 10**9, "training.handover_steps", "LTLNAV_MAX_TIMESTEPS"),
    ("training.cycles", 10**6, "training.cycles", "LTLNAV_MAX_CYCLES"),
    ("training.env.max_steps", 10**9, "training.env.max_steps", "LTLNAV_MAX_EPISODE_STEPS"),
    ("training.env.rays", 10**5, "training.env.rays", "LTLNAV_MAX_RAYS"),
    ("training.hyperparams.batch_size", 10**7, "training.hyperparams.batch_size", "BATCH_SIZE"),
    ("training.hyperparams.gradient_steps", 10**4, "training.hyperparams.gradient_steps", "STEPS"),
    (
        "training.hyperparams.policy_kwargs.n_critics",
        1000,
        "training.hyperparams.policy_kwargs.n_critics",
        "LTLNAV_MAX_CRITICS",
    ),
    (
        "task",
        "([]<>a) && " * 40 + "[]<>b",
        "task",
        "has 82 temporal operators, over the limit 64 (LTLNAV_MAX_TEMPORAL_OPERATORS)",
    ),
    ("task", "[]<>a && " * 300 + "[]<>b", "task", "LTLNAV_MAX_FORMULA_CHARS"),
    ("world.regions.a", {"polygon": polygon(20_000)}, "world.regions.a.polygon", "20000 vertices"),
    ("world.obstacles", [{"polygon": polygon(50_000)}], "world.obstacles.0.polygon", "50000"),
    (
        "world.obstacles",
        [{"box": {"min": [0.1 * i, 2], "max": [0.1 * i + 0.05, 2.1]}} for i in range(600)],
        "world.obstacles",
        "has 600 obstacles, over the limit 500 (LTLNAV_MAX_OBSTACLES)",
    ),
    (
        "world.random_obstacles",
        {"count": 1000, "size": [0.01, 0.01]},
        "world.random_obstacles.count",
        "1000 generated",
    ),
]


@pytest.mark.parametrize(("path", "value", "field", "needle"), HOSTILE)
def test_hostile_documents_are_refused_quickly(
    path: str, value: Any, field: str, needle: str
) -> None:
    document = with_(path, value)
    t0 = time.process_time()
    with pytest.raises(MissionError) as caught:
        admit(document, LIMITS)
    elapsed = time.process_time() - t0
    problems = dict(caught.value.problems)
    assert field in problems, caught.value.problems
    assert needle in problems[field]
    assert elapsed < 1.0


def test_many_polygons_are_refused_by_their_total() -> None:
    regions = {f"r{i}": {"polygon": polygon(300)} for i in range(10)}
    problems = document_problems(with_("world.regions", regions), LIMITS)
    assert problems == [
        (
            "world",
            "has 3000 polygon vertices in all, over the limit 2000 (LTLNAV_MAX_WORLD_VERTICES)",
        )
    ]


def test_a_raised_limit_admits_the_mission() -> None:
    document = with_("training.n_timesteps", 3_000_000)
    with pytest.raises(MissionError):
        admit(document, LIMITS)
    raised = Settings(max_timesteps=5_000_000).admission_limits()
    assert admit(document, raised).training.n_timesteps == 3_000_000


def test_defaults_admit_the_default_sections_and_every_example() -> None:
    spec = admit(copy.deepcopy(TINY), LIMITS)
    spec = spec.model_copy(update={"training": TrainingSpec(), "planner": PlannerSpec()})
    assert mission_problems(spec, LIMITS) == []
    for path in sorted(EXAMPLES.glob("*.yaml")):
        assert load_admitted(path, LIMITS).name == load_mission(path).name


def test_settings_hold_every_limit_with_the_same_default() -> None:
    assert Settings().admission_limits() == AdmissionLimits()


def refused_plan(spec: MissionSpec, folder: Path, limits: AdmissionLimits) -> tuple[str, str]:
    """The one problem ``stored_or_new_plan`` refuses ``spec`` for; no plan is stored."""
    with pytest.raises(MissionError) as caught:
        stored_or_new_plan(spec, folder, limits)
    assert not (folder / "plan.json").exists()
    ((field, message),) = caught.value.problems
    return field, message


def test_a_large_automaton_fails_the_plan_naming_the_limit(tmp_path: Path) -> None:
    document = with_("task", "<>(a && <>b) && <>(b && <>a) && <>(a && <>(b && <>a))")
    spec = admit(document, LIMITS)
    # 26 states before reduction, 10 after: within the translation's budget, over the limit
    field, message = refused_plan(spec, tmp_path, AdmissionLimits(max_automaton_states=9))
    assert field == "task"
    assert "over the limit 9 (LTLNAV_MAX_AUTOMATON_STATES)" in message


def test_a_plan_of_too_many_legs_fails_naming_the_limit_and_the_leg_length(
    tmp_path: Path,
) -> None:
    spec = admit(with_("planner.leg_length", 0.5), LIMITS)
    field, message = refused_plan(spec, tmp_path, AdmissionLimits(max_subtasks=10))
    assert field == "planner.leg_length"
    assert "over the limit 10 (LTLNAV_MAX_SUBTASKS): longer legs make fewer" in message
    plan = stored_or_new_plan(spec, tmp_path, LIMITS)
    assert 10 < len(plan.subtasks) <= LIMITS.max_subtasks
    with pytest.raises(MissionError, match="split the mission"):
        stored_or_new_plan(admit(TINY, LIMITS), tmp_path / "whole", AdmissionLimits(max_subtasks=3))


def test_a_translation_that_outgrows_its_budget_stops_at_once(tmp_path: Path) -> None:
    twenty_goals = " && ".join(f"<>g{i}" for i in range(20))  # 2^20 states
    document = with_("task", twenty_goals)
    document["world"]["regions"] = {f"g{i}": document["world"]["regions"]["a"] for i in range(20)}
    spec = admit(document, LIMITS)
    began = time.process_time()
    with pytest.raises(MissionError) as caught:
        stored_or_new_plan(spec, tmp_path, LIMITS)
    assert time.process_time() - began < 5.0
    ((field, message),) = caught.value.problems
    assert field == "task"
    assert message.startswith(
        "its Büchi automaton grows past 2000 states while translating (4 times the limit 500, "
        "LTLNAV_MAX_AUTOMATON_STATES)"
    )
    assert not (tmp_path / "plan.json").exists()


def test_a_new_plan_translates_the_formula_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Checking the limits and both clearances (the margin does not fit this world) share one
    translation, and the plan is the one ``plan_mission`` makes translating by itself."""
    document = with_("planner.margin", 2.0)
    spec = admit(document, LIMITS)
    calls: list[str] = []
    translate = planner.plan.translate

    def counted(formula: Any, max_states: int | None = None) -> Any:
        calls.append(str(formula))
        return translate(formula, max_states)

    monkeypatch.setattr(planner.plan, "translate", counted)
    plan = stored_or_new_plan(spec, tmp_path, LIMITS)
    assert len(calls) == 1
    assert plan.clearance == spec.robot.radius
    options = spec.planner_options()
    alone = plan_mission(
        spec.build_world(), spec.task, spec.robot.position(), spec.robot.radius, options
    )
    assert len(calls) == 1 + len(MARGIN_SHARES) + 1  # translating by itself: once per attempt
    ignore = ("seconds", "translation_seconds")
    mine, theirs = plan_to_dict(plan), plan_to_dict(alone)
    assert {k: v for k, v in mine.items() if k not in ignore} == {
        k: v for k, v in theirs.items() if k not in ignore
    }
