"""The bundle: written from real (tiny) training runs, read back without unpickling, its
concatenated policy equal to the trained models, and every kind of bad zip refused."""

from __future__ import annotations

import dataclasses
import io
import json
import sys
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import SAC

from envs.mission_env import MissionEnv
from envs.rays import default_ray_range
from envs.robots import robot_params
from planner.errors import LtlnavError
from planner.plan import MissionPlan, plan_mission
from workers.bundle import BundleError, ConcatenatedPolicy, read_bundle, write_bundle
from workers.evaluation import rollout_mission, stage_policies
from workers.jobs import SubtaskJob
from workers.mission import MissionSpec
from workers.run import EVALUATION_SEED
from workers.training import TrainResult, train_subtask

from .missions import tiny_mission


def deterministic(model: SAC) -> Callable[[np.ndarray], np.ndarray]:
    def act(obs: np.ndarray) -> np.ndarray:
        return np.asarray(model.predict(obs, deterministic=True)[0])

    return act


@pytest.fixture(scope="module")
def trained(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[MissionSpec, MissionPlan, list[TrainResult], Path]:
    mission = tiny_mission(n_timesteps=60, eval_freq=60, final_eval_episodes=1)
    plan = plan_mission(
        mission.build_world(),
        mission.task,
        mission.robot.position(),
        mission.robot.radius,
        mission.planner,
    )
    root = tmp_path_factory.mktemp("bundle")
    results = [
        train_subtask(
            mission,
            plan,
            SubtaskJob(subtask=k, training=mission.training, seed=k),
            root / f"subtask_{k}",
        )
        for k in range(len(plan.subtasks))
    ]
    models = [SAC.load(r.model_path, device="cpu") for r in results]
    env = MissionEnv(
        mission, plan, mission.training.eval_env_options(mission.robot.model), cycles=1
    )
    act = stage_policies(env.sequence, [deterministic(m) for m in models])
    evaluation = rollout_mission(act, env, episodes=1)
    env.close()
    seeds = list(range(len(plan.subtasks)))
    bundle = write_bundle(root / "bundle.zip", mission, plan, results, evaluation, seeds)
    return mission, plan, results, bundle


def test_bundle_members_and_manifest(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path],
) -> None:
    mission, plan, results, bundle = trained
    with zipfile.ZipFile(bundle) as archive:
        names = set(archive.namelist())
        manifest = json.loads(archive.read("manifest.json"))
        card = archive.read("README.md").decode()
        assert archive.read("plan.png")[:4] == b"\x89PNG"
    expected = {f"models/subtask_{k}.zip" for k in range(len(plan.subtasks))}
    assert expected | {"manifest.json", "README.md", "plan.png", "learning_curves.png"} <= names
    assert "rollout.png" in names
    assert manifest["format"] == "ltlnav-bundle" and manifest["format_version"] == 3
    assert all(s["drawn"] is None for s in manifest["subtasks"])  # a point robot's polylines
    assert manifest["mission"]["task"] == mission.task
    assert manifest["automaton_hoa"].startswith("HOA: v1")
    assert manifest["seeds"]["subtasks"] == [0, 1, 2, 3]
    assert "stable-baselines3" in manifest["packages"] and "torch" in manifest["packages"]
    assert manifest["plan"]["lasso"]["prefix"][0] == [0.5, 0.5]
    assert "lasso" not in manifest  # the lasso is stored once, in the plan
    assert [s["goal"] for s in manifest["subtasks"]] == [s.goal for s in plan.subtasks]
    for entry, result in zip(manifest["subtasks"], results, strict=True):
        assert entry["steps"] == result.steps == 60
        assert entry["evaluation"]["episodes"] == 1 and len(entry["guide_centers"]) >= 2
        assert entry["policy_kwargs"]["net_arch"] == [8]
    assert manifest["mission_evaluation"]["episodes"] == 1
    assert "tiny-gf2" in card and "| 3 | suffix |" in card


def test_the_manifest_and_card_say_how_the_kept_policy_was_picked(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    mission, plan, results, _ = trained
    trials = [(40, 0.9, 200), (60, 0.5, 20)]
    picked = dataclasses.replace(results[0], policy_steps=40, selection=trials)
    seeds = list(range(len(plan.subtasks)))
    bundle = write_bundle(tmp_path / "b.zip", mission, plan, [picked, *results[1:]], None, seeds)
    with zipfile.ZipFile(bundle) as archive:
        manifest = json.loads(archive.read("manifest.json"))
        card = archive.read("README.md").decode()
    assert manifest["subtasks"][0]["selection"] == [list(t) for t in trials]
    assert manifest["subtasks"][1]["selection"] == []
    assert "policy of step 40, the pick's best of 2: 90.0 % of 200 trials" in card
    assert read_bundle(bundle)[0].subtasks[0].selection == trials


def test_models_load_with_plain_sac(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    *_, bundle = trained
    with zipfile.ZipFile(bundle) as archive:
        archive.extract("models/subtask_2.zip", tmp_path)
    model = SAC.load(tmp_path / "models" / "subtask_2.zip", device="cpu")
    assert model.num_timesteps == 60


def test_concatenated_policy_acts_like_the_trained_models(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path],
) -> None:
    _, _, results, bundle = trained
    policy = ConcatenatedPolicy.load(bundle)
    models = [SAC.load(r.model_path, device="cpu") for r in results]
    env = policy.make_env()
    obs, _ = env.reset(seed=0)
    policy.reset(obs)
    rng = np.random.default_rng(0)
    space = env.observation_space
    assert isinstance(space, spaces.Box)
    low, high = space.low, space.high
    for stage in range(len(env.sequence) + 3):  # beyond the rollout: the suffix cycles on
        probe = obs.copy()
        probe[:-1] = rng.uniform(np.maximum(low[:-1], -1), np.minimum(high[:-1], 1))
        probe[-1] = stage
        k = policy.subtask_of(stage)
        assert k == env.sequence[min(stage, len(env.sequence) - 1)] or stage >= len(env.sequence)
        expected = models[k].predict(probe[:-1], deterministic=True)[0]
        assert np.allclose(policy.act(probe), expected, atol=1e-6)
    assert [policy.subtask_of(s) for s in range(2, 8)] == [2, 3, 2, 3, 2, 3]
    result = policy.evaluate(episodes=1, cycles=1)
    assert result.episodes == 1 and result.cycles == 1
    assert result.success_rate + result.collision_rate + result.timeout_rate + (
        result.rejected_rate
    ) == pytest.approx(1.0)
    env.close()
    policy.close()


def rewrite(bundle: Path, out: Path, change: dict[str, bytes | None]) -> Path:
    """A copy of ``bundle`` with members replaced (bytes), dropped (None) or added."""
    with zipfile.ZipFile(bundle) as src, zipfile.ZipFile(out, "w") as dst:
        for name in src.namelist():
            if name not in change:
                dst.writestr(name, src.read(name))
        for name, data in change.items():
            if data is not None:
                dst.writestr(name, data)
    return out


def manifest_of(bundle: Path) -> dict[str, Any]:
    with zipfile.ZipFile(bundle) as archive:
        manifest: dict[str, Any] = json.loads(archive.read("manifest.json"))
    return manifest


def manifest_with(bundle: Path, **fields: object) -> bytes:
    manifest = manifest_of(bundle)
    manifest.update(fields)
    return json.dumps(manifest).encode()


def test_a_version_1_bundle_with_its_lasso_copy_still_loads(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    *_, bundle = trained
    with zipfile.ZipFile(bundle) as archive:
        plan = json.loads(archive.read("manifest.json"))["plan"]
    old = manifest_with(bundle, format_version=1, lasso=plan["lasso"])
    policy = ConcatenatedPolicy.load(rewrite(bundle, tmp_path / "v1.zip", {"manifest.json": old}))
    assert policy.manifest.lasso == plan["lasso"]
    policy.close()


def test_bad_bundles_are_refused_before_any_model_is_loaded(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    *_, bundle = trained
    assert issubclass(BundleError, LtlnavError)
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(bundle.read_bytes()[: bundle.stat().st_size // 2])
    text = tmp_path / "notes.zip"
    text.write_text("hello")
    foreign = tmp_path / "foreign.zip"
    with zipfile.ZipFile(foreign, "w") as archive:
        archive.writestr("data.csv", "a,b\n1,2\n")
    cases: list[tuple[Path, str]] = [
        (truncated, "not a zip file or corrupted"),
        (text, "not a zip file or corrupted"),
        (foreign, "not an ltlnav bundle"),
        (tmp_path / "missing.zip", "no such bundle"),
        (rewrite(bundle, tmp_path / "a.zip", {"../evil.txt": b"x"}), "path traversal"),
        (rewrite(bundle, tmp_path / "b.zip", {"manifest.json": b"{"}), "not valid JSON"),
        (
            rewrite(
                bundle, tmp_path / "c.zip", {"manifest.json": manifest_with(bundle, format="x")}
            ),
            "not an ltlnav bundle",
        ),
        (
            rewrite(
                bundle,
                tmp_path / "d.zip",
                {"manifest.json": manifest_with(bundle, format_version=9)},
            ),
            "version 9 is not supported",
        ),
        (
            rewrite(bundle, tmp_path / "e.zip", {"manifest.json": manifest_with(bundle, extra=1)}),
            "invalid manifest.json",
        ),
        (rewrite(bundle, tmp_path / "f.zip", {"models/subtask_1.zip": None}), "subtask_1.zip"),
        (rewrite(bundle, tmp_path / "g.zip", {"README.md": None}), "missing"),
    ]
    for path, message in cases:
        with pytest.raises(BundleError, match=message):
            ConcatenatedPolicy.load(path)


def test_a_model_archive_with_foreign_members_or_wrong_weights_is_refused(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    *_, bundle = trained
    with zipfile.ZipFile(bundle) as archive:
        model = archive.read("models/subtask_0.zip")
        manifest = json.loads(archive.read("manifest.json"))
    buffer = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(model)) as src, zipfile.ZipFile(buffer, "w") as dst:
        for name in src.namelist():
            dst.writestr(name, src.read(name))
        dst.writestr("payload.pkl", b"cos\nsystem\n(S'true'\ntR.")
    evil = rewrite(bundle, tmp_path / "evil.zip", {"models/subtask_0.zip": buffer.getvalue()})
    with pytest.raises(BundleError, match="unexpected members"):
        read_bundle(evil)
    manifest["subtasks"][0]["policy_kwargs"]["net_arch"] = [16, 16]
    wrong = rewrite(
        bundle, tmp_path / "wrong.zip", {"manifest.json": json.dumps(manifest).encode()}
    )
    with pytest.raises(BundleError, match="do not fit"):
        ConcatenatedPolicy.load(wrong)
    manifest["subtasks"][0]["policy_kwargs"]["net_arch"] = [8]
    manifest["subtasks"][0]["model"] = "../models/subtask_0.zip"
    escape = rewrite(
        bundle, tmp_path / "escape.zip", {"manifest.json": json.dumps(manifest).encode()}
    )
    with pytest.raises(BundleError, match="missing or misnamed"):
        read_bundle(escape)


@pytest.mark.parametrize("algorithm", ["td3", "ppo"])
def test_policies_of_other_algorithms_are_rebuilt_without_unpickling(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path],
    tmp_path: Path,
    algorithm: str,
) -> None:
    from stable_baselines3 import PPO, TD3

    from workers.bundle_reader import build_policy
    from workers.manifest import SubtaskEntry
    from workers.training_spec import TrainingSpec

    mission, plan, _, _ = trained
    extra = {"n_steps": 32, "batch_size": 16} if algorithm == "ppo" else {}
    kwargs = {"net_arch": [8], "activation_fn": "tanh"}
    training = TrainingSpec.model_validate(
        {
            **mission.training.model_dump(),
            "algorithm": algorithm,
            "n_timesteps": 40,
            "eval_freq": 40,
            "final_eval_episodes": 1,
            "hyperparams": {"policy_kwargs": kwargs, **extra},
        }
    )
    spec = SubtaskJob(subtask=1, training=training, seed=0)
    result = train_subtask(mission, plan, spec, tmp_path / algorithm)
    blob = Path(result.model_path).read_bytes()
    entry = SubtaskEntry(
        index=1,
        phase="prefix",
        goal="b",
        start=[0.0, 0.0],
        path=[[0.0, 0.0]],
        r_ball=0.1,
        guide_centers=[[0.0, 0.0]],
        model="models/subtask_1.zip",
        algorithm=algorithm,
        policy_kwargs=kwargs,
        seed=0,
        steps=40,
        stopped="budget",
        curve=[],
        evaluation=None,
    )
    env = MissionEnv(mission, plan, training.eval_env_options(mission.robot.model), cycles=1)
    policy = build_policy(entry, blob, env)
    model = (PPO if algorithm == "ppo" else TD3).load(result.model_path, device="cpu")
    obs, _ = env.envs[1].reset(seed=0)
    assert np.allclose(
        policy.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0]
    )
    env.close()


def test_loading_a_bundle_unpickles_nothing(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import pickle

    import cloudpickle

    def refuse(*_: object, **__: object) -> None:
        raise AssertionError("a bundle must not be unpickled")

    for module, name in [(pickle, "loads"), (pickle, "load"), (cloudpickle, "loads")]:
        monkeypatch.setattr(module, name, refuse)
    monkeypatch.setattr(pickle, "Unpickler", refuse)
    *_, bundle = trained
    policy = ConcatenatedPolicy.load(bundle)
    assert len(policy.policies) == 4
    policy.close()


def test_policies_act_under_the_recorded_env_options(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    mission, _, _, bundle = trained
    manifest = manifest_of(bundle)
    expected = mission.training.eval_env_options(mission.robot.model)
    assert manifest["eval_env"]["rays"] == expected.rays
    assert manifest["eval_env"]["start_noise"] == expected.start_noise
    # the defaults of a later ltlnav may differ: the recorded options win
    recorded = {**manifest["eval_env"], "max_steps": 7}
    changed = rewrite(
        bundle, tmp_path / "h.zip", {"manifest.json": manifest_with(bundle, eval_env=recorded)}
    )
    policy = ConcatenatedPolicy.load(changed)
    try:
        env = policy.make_env()
        assert {e.max_steps for e in env.envs} == {7}
        env.close()
    finally:
        policy.close()
    bad = rewrite(
        bundle,
        tmp_path / "i.zip",
        {"manifest.json": manifest_with(bundle, eval_env={**recorded, "rays": -1})},
    )
    with pytest.raises(BundleError, match="invalid eval_env"):
        ConcatenatedPolicy.load(bad)
    older = {k: v for k, v in manifest.items() if k != "eval_env"}
    legacy = rewrite(bundle, tmp_path / "j.zip", {"manifest.json": json.dumps(older).encode()})
    ConcatenatedPolicy.load(legacy).close()  # bundles written before the field still load


def test_the_start_spread_bench_is_the_bundle_s_own_evaluation_at_its_spread(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path],
) -> None:
    """``bench/start_noise.py``: at the recorded spread, on one lane, its rollouts are the
    policy's own evaluation at the reported seed; with no spread every rollout starts alike,
    the policy's and the zero action's."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import start_noise

    mission, _, _, bundle = trained
    policy = ConcatenatedPolicy.load(bundle)
    try:
        options = policy.options()
        recorded = (options.start_noise, options.heading_noise)
        assert recorded[0] > 0
        ours = start_noise.rollouts(policy, recorded, 3, lanes=1)
        own = policy.evaluate(3, seed=mission.training.seed + EVALUATION_SEED)
        assert ours.trails == own.trails and ours.success_rate == own.success_rate
        assert len({tuple(trail[0]) for trail in ours.trails}) == 3
        for control in (False, True):
            still = start_noise.rollouts(policy, (0.0, 0.0), 3, lanes=1, control=control)
            assert len({tuple(trail[0]) for trail in still.trails}) == 1
            assert still.success_rate in (0.0, 1.0)
    finally:
        policy.close()


def ray_ranges(bundle: Path) -> list[float]:
    policy = ConcatenatedPolicy.load(bundle)
    try:
        env = policy.make_env()
        ranges = {e.ray_caster.max_range for e in env.envs if e.ray_caster is not None}
        env.close()
        return sorted(ranges)
    finally:
        policy.close()


def test_a_bundle_s_policies_see_as_far_as_in_training_whatever_the_default(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    mission, _, _, bundle = trained
    manifest = manifest_of(bundle)
    assert manifest["eval_env"]["rays"] > 0
    trained_range = default_ray_range(robot_params(mission.robot.model, mission.robot.params))
    assert manifest["eval_env"]["ray_range"] == pytest.approx(trained_range)
    assert ray_ranges(bundle) == [pytest.approx(trained_range)]
    # bundles written while the range was an eighth of the world's diagonal keep it
    world_scaled = mission.build_world().diagonal / 8.0
    assert world_scaled != pytest.approx(trained_range)
    unresolved = {**manifest["eval_env"], "ray_range": None}
    old = rewrite(
        bundle, tmp_path / "k.zip", {"manifest.json": manifest_with(bundle, eval_env=unresolved)}
    )
    assert ray_ranges(old) == [pytest.approx(world_scaled)]
    older = {k: v for k, v in manifest.items() if k != "eval_env"}
    legacy = rewrite(bundle, tmp_path / "l.zip", {"manifest.json": json.dumps(older).encode()})
    assert ray_ranges(legacy) == [pytest.approx(world_scaled)]


def test_a_bundle_whose_guides_this_ltlnav_draws_otherwise_says_so(
    trained: tuple[MissionSpec, MissionPlan, list[TrainResult], Path], tmp_path: Path
) -> None:
    """A bundle trained before a change to how guides are drawn still loads, and its load
    names the sub-tasks whose guide its rollouts will follow differently; a bundle of today's
    code names none."""
    *_, bundle = trained
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        policy = ConcatenatedPolicy.load(bundle)
    assert policy.redrawn_subtasks() == []
    policy.close()
    with zipfile.ZipFile(bundle) as archive:
        manifest = json.loads(archive.read("manifest.json"))
    moved = [[x + 0.05 for x in c] for c in manifest["subtasks"][1]["guide_centers"]]
    manifest["subtasks"][1]["guide_centers"] = moved
    older = rewrite(bundle, tmp_path / "k.zip", {"manifest.json": json.dumps(manifest).encode()})
    with pytest.warns(UserWarning, match=r"sub-tasks \[1\] differently"):
        policy = ConcatenatedPolicy.load(older)
    policy.close()
