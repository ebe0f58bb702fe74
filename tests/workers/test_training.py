"""Training one sub-task for real with tiny budgets: checkpoints, resume, cancel, what the hooks
hear, the training section's validation, the plan document and the job value."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import DummyVecEnv

from planner.plan import MissionPlan
from planner.serialize import plan_from_dict, plan_to_dict
from workers.agents import OFF_POLICY_TRAIN_FREQ, keep_best_policy
from workers.callbacks import (
    ResumableEvalCallback,
    StopOnSuccessRate,
    evaluations_since_best,
    plateau_level,
    plateaued,
)
from workers.evaluation import SubtaskEvaluation
from workers.jobs import SubtaskJob
from workers.mission import MissionError, MissionSpec
from workers.training import TrainingError, TrainResult, subtask_env, train_subtask
from workers.training_spec import TrainingSpec

from .missions import Recorder, tiny_mission


def job(mission: MissionSpec, subtask: int = 0, **training: Any) -> SubtaskJob:
    spec = TrainingSpec.model_validate({**mission.training.model_dump(), **training})
    return SubtaskJob(subtask=subtask, training=spec, seed=3)


def test_plan_document_round_trips_exactly(plan: MissionPlan) -> None:
    doc = plan_to_dict(plan)
    again = plan_from_dict(json.loads(json.dumps(doc)))
    assert plan_to_dict(again) == doc
    assert again.nba.accepting == plan.nba.accepting and again.pruned.edges == plan.pruned.edges
    for a, b in zip(again.subtasks, plan.subtasks, strict=True):
        assert np.array_equal(a.path, b.path) and a.goal == b.goal
    del doc["hold"]  # a plan stored before plans recorded it sought no more than it kept
    assert plan_from_dict(doc).hold == plan.clearance


def test_a_job_is_a_small_value_that_round_trips_through_json(mission: MissionSpec) -> None:
    spec = job(mission)
    assert SubtaskJob.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    assert set(spec.to_json()) == {"subtask", "training", "seed", "round", "starts", "warm_start"}


def test_unknown_hyperparameter_names_the_key_and_the_valid_ones() -> None:
    with pytest.raises(MissionError) as caught:
        tiny_mission(hyperparams={"learnin_rate": 0.001})
    message = str(caught.value)
    assert "training.hyperparams.learnin_rate" in message and "learning_rate" in message
    with pytest.raises(MissionError, match=r"training\.hyperparams\.buffer_size: unknown ppo"):
        tiny_mission(algorithm="ppo", hyperparams={"buffer_size": 10})
    with pytest.raises(MissionError, match=r"policy_kwargs\.net_arc"):
        tiny_mission(hyperparams={"policy_kwargs": {"net_arc": [8]}})
    with pytest.raises(MissionError, match=r"training\.env\.lookahed"):
        tiny_mission(env={"lookahed": 2})
    with pytest.raises(MissionError, match=r"training\.reward\.constants\.step_cost"):
        tiny_mission(reward={"mode": "ned", "constants": {"step_cost": 0.1}})


def test_defaults_are_the_papers_network() -> None:
    spec = TrainingSpec()
    assert spec.algorithm == "sac" and spec.target_success == 0.95
    assert spec.final_eval_episodes == 200 and spec.torch_threads == 1
    assert spec.plateau_evals == 6 and spec.pick_candidates == 3  # measured: bench/LEARNING.md
    assert spec.policy_kwargs() == {"net_arch": [64, 64, 64], "activation_fn": "relu"}


def test_train_checkpoint_then_resume_with_a_bigger_budget(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scratch = tmp_path / "tmpdir"
    scratch.mkdir()
    monkeypatch.setenv("TMPDIR", str(scratch))
    out = tmp_path / "job"
    hooks = Recorder()
    first = train_subtask(mission, plan, job(mission), out, hooks)
    seen = hooks.progressed
    assert (first.steps, first.resumed_from, first.stopped) == (200, 0, "budget")
    assert [s for s, _ in first.curve] == [100, 200]
    assert first.final is not None and first.final["episodes"] == 2
    rates = first.final
    kinds = ("success_rate", "collision_rate", "timeout_rate", "rejected_rate")
    assert sum(rates[k] for k in kinds) == 1
    assert seen[0][0] == 0 and seen[-1][0] == 200 and all(t == 200 for *_, t in seen)
    assert [a[0] for a in seen] == sorted(a[0] for a in seen)
    assert (out / "checkpoints" / "model_200_steps.zip").is_file()
    assert (out / "checkpoints" / "model_replay_buffer_200_steps.pkl").is_file()
    assert (out / "logs" / "run_0" / "progress.csv").is_file()
    assert list((out / "logs" / "run_0").glob("events.out.tfevents.*")), "no TensorBoard log"
    assert list(scratch.iterdir()) == []  # nothing written to $TMPDIR
    assert hooks.resumes == [0]
    assert [(p.steps, p.episodes) for p in hooks.points] == [(100, 1), (200, 1)]
    assert [p.success_rate for p in hooks.points] == [r for _, r in first.curve]
    assert [s for s, _ in hooks.saved] == [100, 200, 200]  # periodic, then the final one
    assert hooks.saved[-1][1] == out / "checkpoints" / "model_200_steps.zip"
    model = SAC.load(first.model_path, device="cpu")
    assert model.num_timesteps == 200

    again_hooks = Recorder()
    second = train_subtask(mission, plan, job(mission, n_timesteps=350), out, again_hooks)
    assert again_hooks.resumes == [200] and [p.steps for p in again_hooks.points] == [300]
    assert (second.resumed_from, second.steps) == (200, 350)
    with np.load(out / "evaluations.npz") as data:
        assert data["timesteps"].tolist() == [100, 200, 300]
    assert [s for s, _ in second.curve] == [100, 200, 300]
    assert (out / "logs" / "run_200" / "progress.csv").is_file()
    again = train_subtask(mission, plan, job(mission, n_timesteps=350), out)
    assert again == second  # a finished job returns its stored result


def test_cancel_stops_after_a_checkpoint_and_resumes(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    out = tmp_path / "job"
    asked: list[bool] = []

    def should_stop() -> bool:  # no before training starts, yes at the first step
        asked.append(True)
        return len(asked) > 1

    stopped = train_subtask(mission, plan, job(mission, subtask=1), out, Recorder(should_stop))
    assert stopped.stopped == "cancelled" and stopped.steps == 1 and stopped.final is None
    assert Path(stopped.model_path).is_file() and not (out / "result.json").exists()
    # a newer checkpoint cut short (the job was killed while writing it) is skipped
    (out / "checkpoints" / "model_50_steps.zip").write_bytes(b"PK\x03\x04 cut short")
    with pytest.warns(UserWarning, match="model_50_steps.zip"):
        resumed = train_subtask(mission, plan, job(mission, subtask=1, n_timesteps=120), out)
    assert (resumed.resumed_from, resumed.stopped) == (1, "budget")
    # SB3 collects train_freq steps between updates: from an odd step it ends one past
    assert 120 <= resumed.steps < 120 + OFF_POLICY_TRAIN_FREQ


def test_same_seed_same_policy(mission: MissionSpec, plan: MissionPlan, tmp_path: Path) -> None:
    spec = job(mission, subtask=2, n_timesteps=80, eval_freq=80, final_eval_episodes=1)
    a = SAC.load(train_subtask(mission, plan, spec, tmp_path / "a").model_path, device="cpu")
    b = SAC.load(train_subtask(mission, plan, spec, tmp_path / "b").model_path, device="cpu")
    env = subtask_env(mission, plan, spec.training, 2, evaluation=True)
    obs, _ = env.reset(seed=0)
    env.close()
    for key, value in a.policy.state_dict().items():
        assert np.array_equal(value.numpy(), b.policy.state_dict()[key].numpy()), key
    assert np.array_equal(
        a.predict(obs, deterministic=True)[0], b.predict(obs, deterministic=True)[0]
    )


def test_bad_subtask_index_is_a_training_error(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    with pytest.raises(TrainingError, match="does not exist"):
        train_subtask(mission, plan, job(mission, subtask=99), tmp_path / "job")
    assert not (tmp_path / "job").exists()


def test_stop_on_success_rate_reads_the_last_evaluation(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    env = subtask_env(mission, plan, mission.training, 0, evaluation=True)
    stopper = StopOnSuccessRate(0.6)
    evaluation = ResumableEvalCallback(env, callback_after_eval=stopper, verbose=0)
    evaluation.evaluations_successes = [[True, False, False]]
    assert stopper._on_step() and not stopper.reached
    evaluation.evaluations_successes.append([True, True, False])
    assert not stopper._on_step() and stopper.reached
    assert evaluation.last_success_rate == pytest.approx(2 / 3)
    env.close()


def test_a_periodic_success_stops_only_when_the_confirmation_reaches_the_target(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    env = subtask_env(mission, plan, mission.training, 0, evaluation=True)
    rates = iter([0.5, 0.75])

    def confirm() -> SubtaskEvaluation:
        return SubtaskEvaluation(4, next(rates), 0.0, 0.0, None)

    stopper = StopOnSuccessRate(0.6, confirm)
    evaluation = ResumableEvalCallback(env, callback_after_eval=stopper, verbose=0)
    model = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, learning_starts=10)
    model.set_logger(Logger(folder=None, output_formats=[]))
    evaluation.init_callback(model)
    evaluation.evaluations_successes = [[True, True, False]]
    assert stopper._on_step() and not stopper.reached and stopper.confirmed is None
    assert not stopper._on_step() and stopper.reached
    assert stopper.confirmed is not None and stopper.confirmed.success_rate == 0.75
    assert [rate for _, rate in stopper.confirmations] == [0.5, 0.75]
    env.close()


def test_the_reported_evaluation_is_measured_once_after_every_decision_on_a_seed_of_its_own(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every periodic evaluation reaches the target; the first confirmation fails, the second
    passes and stops training; the reported evaluation is run once at the end on the report
    seed, which no decision used, and its rate is reported even below the target."""
    import workers.training as training_module

    asked: list[tuple[int, int, int]] = []
    rates: Iterator[float | tuple[float, int]] = iter([(0.5, 14), 1.0, 0.3])

    def scripted(
        act: Any, envs: Any, episodes: int, seed: int, needed: int = 0
    ) -> SubtaskEvaluation:
        asked.append((episodes, seed, needed))
        rate = next(rates)
        if isinstance(rate, tuple):  # out of reach after 7 failures in 14: stopped there
            rate, episodes = rate
        return SubtaskEvaluation(episodes, rate, 0.0, 0.0, None)

    monkeypatch.setattr(training_module, "evaluate_subtask", scripted)
    monkeypatch.setattr(ResumableEvalCallback, "last_success_rate", property(lambda _: 1.0))
    spec = job(mission, n_timesteps=400, eval_freq=100, final_eval_episodes=20)
    result = train_subtask(mission, plan, spec, tmp_path)
    assert result.stopped == "target" and result.steps == 200
    assert result.confirmations == [(100, 0.5, 14), (200, 1.0, 20)]
    assert result.final is not None and result.final["success_rate"] == 0.3
    assert [(episodes, needed) for episodes, _, needed in asked] == [(20, 19), (20, 19), (20, 0)]
    report = spec.seed + training_module.REPORT_SEED
    assert [seed for _, seed, _ in asked] == [
        spec.seed + training_module.CONFIRMATION_SEED,
        spec.seed + training_module.CONFIRMATION_SEED + 1,
        report,
    ]
    assert report != spec.seed + training_module.PERIODIC_SEED
    stored = json.loads((tmp_path / "confirmations.json").read_text())
    assert stored == [[100, 0.5, 14], [200, 1.0, 20]]
    assert TrainResult.from_json(result.to_json()) == result
    older = {**result.to_json(), "confirmations": [[100, 0.5], [200, 1.0]]}
    assert TrainResult.from_json(older).confirmations == [(100, 0.5, None), (200, 1.0, None)]


def test_a_stored_result_below_a_raised_target_trains_on(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    first = train_subtask(mission, plan, job(mission), tmp_path)
    stored = json.loads((tmp_path / "result.json").read_text())
    stored["stopped"] = "target"
    stored["confirmations"] = [[first.steps, 0.5]]  # the one that stopped it
    stored["final"]["success_rate"] = 0.9  # reported: decides nothing
    (tmp_path / "result.json").write_text(json.dumps(stored))
    bigger = first.steps + 100
    raised = job(mission, target_success=0.4, n_timesteps=bigger)
    kept = train_subtask(mission, plan, raised, tmp_path)
    assert kept.stopped == "target" and kept.steps == first.steps
    higher = job(mission, target_success=0.6, n_timesteps=bigger)
    again = train_subtask(mission, plan, higher, tmp_path)
    assert again.resumed_from == first.steps and again.steps == bigger


@pytest.mark.parametrize(
    ("algorithm", "hyperparams"),
    [
        ("td3", {"noise_type": "normal", "noise_std": 0.2, "train_freq": [1, "step"]}),
        ("ddpg", {"noise_type": "ornstein-uhlenbeck", "learning_starts": 20}),
        ("ppo", {"n_steps": 32, "batch_size": 16, "n_epochs": 1}),
    ],
)
def test_other_algorithms_train_with_rl_zoo_hyperparameters(
    mission: MissionSpec,
    plan: MissionPlan,
    tmp_path: Path,
    algorithm: str,
    hyperparams: dict[str, Any],
) -> None:
    hyperparams = {**hyperparams, "policy_kwargs": {"net_arch": [8], "activation_fn": "tanh"}}
    spec = job(
        mission,
        algorithm=algorithm,
        hyperparams=hyperparams,
        n_timesteps=64,
        eval_freq=64,
        final_eval_episodes=1,
    )
    result = train_subtask(mission, plan, spec, tmp_path / algorithm)
    assert result.steps >= 64 and result.final is not None
    assert Path(result.model_path).is_file()


def test_whole_lasso_mode_trains_one_agent(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    spec = job(
        mission, reward={"mode": "g-rrt"}, n_timesteps=64, eval_freq=64, final_eval_episodes=1
    )
    env = subtask_env(mission, plan, spec.training, 0)
    assert len(env.legs) == len(plan.subtasks)  # one course through every sub-task
    env.close()
    assert train_subtask(mission, plan, spec, tmp_path / "g").steps == 64


def test_the_best_evaluation_keeps_its_policy(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    out = tmp_path / "job"
    result = train_subtask(mission, plan, job(mission, n_timesteps=200), out)
    record = json.loads((out / "best_model.json").read_text())
    rates = [r for _, r in result.curve]
    assert record == {"steps": result.curve[rates.index(max(rates))][0], "success_rate": max(rates)}
    assert SAC.load(out / "best_model.zip", device="cpu").num_timesteps == record["steps"]
    assert result.policy_steps == (record["steps"] if max(rates) > rates[-1] else None)


def test_evaluations_since_best_count_from_the_first_highest_rate() -> None:
    assert evaluations_since_best([]) == 0
    assert evaluations_since_best([(0, 0.5)]) == 0
    assert evaluations_since_best([(0, 0.5), (5, 0.8), (10, 0.8), (15, 0.7)]) == 2
    assert evaluations_since_best([(0, 0.5), (5, 0.8), (10, 0.9)]) == 0
    curve = [(0, 0.5), (5, 0.8), (10, 0.8), (15, 0.7)]
    assert plateaued(curve, 2, 0.8, 50) and not plateaued(curve, 3, 0.8, 50)
    assert not plateaued(curve, 2, 0.85, 50) and not plateaued(curve, None, 0.0, 50)


def test_a_fall_after_the_best_is_no_plateau_and_one_dip_does_not_hide_one() -> None:
    assert plateau_level(0.9, 50) == pytest.approx(0.815, abs=0.001)
    assert plateau_level(0.0, 50) == 0.0 and plateau_level(1.0, 50) == 1.0
    steps = range(0, 35_000, 5_000)
    fallen = list(zip(steps, [0.92, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], strict=True))
    collapse = list(zip(steps, [0.96, 0.86, 0.22, 0.0, 0.42, 0.14, 0.0], strict=True))
    flat = list(zip(steps, [0.92, 0.88, 0.84, 0.9, 0.86, 0.0, 0.9], strict=True))
    assert not plateaued(fallen, 6, 0.9, 50) and not plateaued(collapse, 6, 0.9, 50)
    assert plateaued(flat, 6, 0.9, 50)
    assert not plateaued(flat, 6, 0.9, 1_000)  # with 1000 episodes 0.87 is below 0.9's level


def test_a_plateau_stops_training_keeps_the_best_and_a_raised_patience_trains_on(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    out = tmp_path / "job"
    spec = job(mission, n_timesteps=1000, eval_freq=100, plateau_evals=2, plateau_from=0.0)
    flat = job(mission, n_timesteps=300, eval_freq=100, plateau_evals=1, plateau_from=1.0)
    low = train_subtask(mission, plan, flat, tmp_path / "low")
    assert low.stopped != "plateau" or max(r for _, r in low.curve) == 1.0
    first = train_subtask(mission, plan, spec, out)
    # rates are 0 or 1 (one episode each): the best rises at most once, so 2 evaluations
    # without a new best come by step 500
    assert first.stopped == "plateau" and first.steps == first.curve[-1][0] <= 500
    assert evaluations_since_best(first.curve) == 2
    rates = [r for _, r in first.curve]
    record = json.loads((out / "best_model.json").read_text())
    assert record["steps"] == first.curve[rates.index(max(rates))][0]
    assert first.policy_steps == (record["steps"] if max(rates) > rates[-1] else None)
    assert train_subtask(mission, plan, spec, out).steps == first.steps  # finished: kept
    patient = job(mission, n_timesteps=1000, eval_freq=100, plateau_evals=3, plateau_from=0.0)
    more = train_subtask(mission, plan, patient, out)
    assert more.resumed_from == first.steps and more.curve[: len(first.curve)] == first.curve
    assert more.stopped == "plateau" and evaluations_since_best(more.curve) == 3
    unbounded = train_subtask(mission, plan, job(mission, n_timesteps=1000, eval_freq=100), out)
    assert unbounded.stopped in ("budget", "target") and unbounded.resumed_from == more.steps


def test_a_budget_run_out_after_unlearning_keeps_thekeep_best_policy(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    training = mission.training
    env = DummyVecEnv([lambda: subtask_env(mission, plan, training, 0)])
    best = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=1, device="cpu")
    last = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=2, device="cpu")
    path = tmp_path / "best_model.zip"
    best.save(path)
    path.with_suffix(".json").write_text(json.dumps({"steps": 100, "success_rate": 1.0}))
    evaluation = ResumableEvalCallback(env, verbose=0, best_path=path)
    evaluation.restore(150)
    assert evaluation.best == (100, 1.0)
    evaluation.evaluations_successes = [[True, True], [True, False]]
    kept, steps = keep_best_policy(last, evaluation, training, env)
    assert steps == 100
    for key, value in best.policy.state_dict().items():
        assert np.array_equal(value.numpy(), kept.policy.state_dict()[key].numpy()), key
    evaluation.evaluations_successes.append([True, True])
    assert keep_best_policy(last, evaluation, training, env) == (last, None)
    stale = ResumableEvalCallback(env, verbose=0, best_path=path)
    stale.restore(50)  # the kept policy is from a step the resumed run redoes
    assert stale.best is None
    env.close()
