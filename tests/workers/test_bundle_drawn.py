"""A car's bundle records the drivable paths its policies were trained on and drives them,
whatever a later ltlnav's redraw would make of the plan's polylines."""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3 import SAC

import envs.factory
from envs.drivable import redraw_course
from envs.factory import drawn_subtasks, make_env
from envs.options import EnvOptions
from planner.decompose import SubTask
from planner.geometry.pose import Pose
from planner.geometry.world import World
from planner.plan import MissionPlan, plan_mission
from planner.serialize import plan_from_dict, plan_to_dict
from workers.bundle import BundleError, ConcatenatedPolicy, write_bundle
from workers.mission import MissionSpec, parse_mission
from workers.training import TrainResult

from .test_bundle import manifest_of, manifest_with, rewrite

LANE: dict[str, Any] = {
    "name": "racecar-lane",
    "task": "<>(a && <>b)",
    "robot": {"model": "racecar", "start": [1.5, 1.5, 0.0]},
    "planner": {"seed": 0, "refine_iterations": 300},
    "world": {
        "bounds": [[0, 12], [0, 5]],
        "obstacles": [{"box": {"min": [4.0, 3.2], "max": [8.0, 5.0]}}],
        "regions": {
            "a": {"ball": {"center": [10.5, 2.0], "radius": 0.8}},
            "b": {"ball": {"center": [1.5, 3.8], "radius": 0.6}},
        },
    },
    "training": {"hyperparams": {"policy_kwargs": {"net_arch": [8]}}},
}
"""East down a lane into ``a``, then back west to ``b``: a U-turn the racecar makes on a loop."""


@pytest.fixture(scope="module")
def lane_bundle(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[MissionSpec, MissionPlan, Path]:
    """A racecar bundle of untrained policies (what is tested is the guides, not the actions)."""
    mission = parse_mission(LANE)
    world = mission.build_world()
    plan = plan_mission(
        world, mission.task, mission.robot.position(), mission.robot.radius, mission.planner
    )
    root = tmp_path_factory.mktemp("lane")
    options = mission.training.eval_env_options("racecar")
    results = []
    for k in range(len(plan.subtasks)):
        env = make_env(mission, k, world=world, plan=plan, options=options)
        path = root / f"subtask_{k}.zip"
        SAC("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, device="cpu").save(path)
        env.close()
        results.append(TrainResult(k, k, str(path), 0, 0, "target"))
    seeds = list(range(len(plan.subtasks)))
    return mission, plan, write_bundle(root / "bundle.zip", mission, plan, results, None, seeds)


def rollout_guides(policy: ConcatenatedPolicy) -> list[np.ndarray]:
    env = policy.make_env(cycles=1)
    try:
        return [np.concatenate([leg.guide.centers for leg in e.legs]) for e in env.envs]
    finally:
        env.close()


def trained_guides(bundle: Path) -> list[np.ndarray]:
    return [np.asarray(s["guide_centers"]) for s in manifest_of(bundle)["subtasks"]]


@pytest.fixture
def redrawn_otherwise(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Today's redraw turns wider than the one the bundle was trained with."""

    def wider(
        world: World, pool: list[SubTask], start: Pose, rho: float, steps: list[float]
    ) -> list[SubTask]:
        return redraw_course(world, pool, start, 1.3 * rho, steps)

    monkeypatch.setattr(envs.factory, "redraw_course", wider)
    yield


def test_a_car_s_bundle_records_the_paths_it_was_trained_on(
    lane_bundle: tuple[MissionSpec, MissionPlan, Path],
) -> None:
    mission, plan, bundle = lane_bundle
    options = mission.training.eval_env_options("racecar")
    drawn = drawn_subtasks(mission, plan, options, mission.build_world())
    assert drawn is not None
    entries = manifest_of(bundle)["subtasks"]
    assert manifest_of(bundle)["format_version"] == 3
    for entry, sub, polyline in zip(entries, drawn, plan.subtasks, strict=True):
        assert np.array_equal(entry["drawn"]["path"], sub.path)
        assert entry["drawn"]["reverse"] == sub.reverse
        assert len(sub.path) > len(polyline.path)  # dense, not the plan's polyline
    pointless = drawn_subtasks(mission, plan, EnvOptions(), mission.build_world())
    assert pointless is None  # no drivable guide: the envs drive the plan's polylines


@pytest.mark.usefixtures("redrawn_otherwise")
def test_a_bundle_drives_its_recorded_guides_when_today_s_redraw_differs(
    lane_bundle: tuple[MissionSpec, MissionPlan, Path], tmp_path: Path
) -> None:
    _, _, bundle = lane_bundle
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        policy = ConcatenatedPolicy.load(bundle)
    try:
        assert policy.redrawn_subtasks() == []
        for drove, trained in zip(rollout_guides(policy), trained_guides(bundle), strict=True):
            assert np.array_equal(drove, trained)
    finally:
        policy.close()
    # a bundle written before the record follows today's redraw, and says so
    manifest = manifest_of(bundle)
    for entry in manifest["subtasks"]:
        del entry["drawn"]
    older = rewrite(bundle, tmp_path / "v2.zip", {"manifest.json": json.dumps(manifest).encode()})
    with pytest.warns(UserWarning, match="differently from those they were trained on"):
        policy = ConcatenatedPolicy.load(older)
    try:
        assert policy.redrawn_subtasks()
        redrawn = rollout_guides(policy)
        assert any(
            d.shape != t.shape or not np.allclose(d, t)
            for d, t in zip(redrawn, trained_guides(bundle), strict=True)
        )
    finally:
        policy.close()


def test_bad_drawn_guides_are_refused(
    lane_bundle: tuple[MissionSpec, MissionPlan, Path], tmp_path: Path
) -> None:
    _, _, bundle = lane_bundle
    entries = manifest_of(bundle)["subtasks"]
    first = entries[0]["drawn"]
    cases = {
        "others do not": [{**entries[0], "drawn": None}, *entries[1:]],
        "not a 2D path": [{**entries[0], "drawn": {**first, "path": [[1.0, 2.0, 3.0]]}}],
        "malformed": [{**entries[0], "drawn": {**first, "path": [[1.0], [1.0, 2.0]]}}],
        "backs up past its end": [
            {**entries[0], "drawn": {**first, "reverse": len(first["path"])}}
        ],
    }
    for k, (message, changed) in enumerate(cases.items()):
        subtasks = [*changed, *entries[len(changed) :]]
        manifest = manifest_with(bundle, subtasks=subtasks)
        bad = rewrite(bundle, tmp_path / f"bad{k}.zip", {"manifest.json": manifest})
        with pytest.raises(BundleError, match=message):
            ConcatenatedPolicy.load(bad)


def test_a_plan_s_drawn_paths_survive_its_json(
    lane_bundle: tuple[MissionSpec, MissionPlan, Path],
) -> None:
    mission, plan, _ = lane_bundle
    drawn = drawn_subtasks(mission, plan, mission.training.eval_env_options("racecar"))
    assert drawn is not None
    fixed = plan_from_dict(plan_to_dict(dataclasses.replace(plan, drawn=drawn)))
    assert fixed.drawn is not None
    for back, sub in zip(fixed.drawn, drawn, strict=True):
        assert np.array_equal(back.path, sub.path) and back.reverse == sub.reverse
    assert "drawn" not in plan_to_dict(plan)  # a plan's digest is unchanged without one
