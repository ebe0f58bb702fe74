"""Hand-over repair: which sub-tasks train on, from which poses, and which rounds are kept; a
warm-started job trains for real from a finished job's policy and replay buffer."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import SAC

from envs.errors import EnvConfigError
from envs.factory import make_env
from planner.geometry.pose import Pose
from planner.plan import MissionPlan
from workers.evaluation import MissionEvaluation
from workers.handover_repair import (
    MAX_STARTS,
    REPAIR_CURRICULUM,
    RepairRound,
    merged,
    repair_jobs,
    start_poses,
)
from workers.jobs import SubtaskJob
from workers.mission import MissionSpec
from workers.run import EVALUATION_SEED, SELECTION_SEED, MissionRun
from workers.training import TrainingError, TrainResult, subtask_env, train_subtask
from workers.training_spec import TrainingSpec

from .missions import tiny_mission


def result(k: int, folder: Path, steps: int = 200, success: float = 0.5) -> TrainResult:
    return TrainResult(
        subtask=k,
        seed=10 + k,
        model_path=str(folder / f"subtask_{k}" / "model.zip"),
        steps=steps,
        resumed_from=0,
        stopped="budget",
        curve=[(100, 0.0), (steps, success)],
        final={"episodes": 2, "success_rate": success},
        seconds=3.0,
    )


def evaluation(success: float, failures: dict[str, dict[str, int]]) -> MissionEvaluation:
    poses = {k: [Pose(np.array([1.0 + 0.1 * i, 2.0]), 0.5 * i) for i in range(3)] for k in range(4)}
    return MissionEvaluation(
        episodes=10,
        cycles=3,
        success_rate=success,
        collision_rate=1 - success,
        timeout_rate=0.0,
        rejected_rate=0.0,
        mean_steps=None,
        failures=failures,
        handovers=poses,
    )


def test_only_subtasks_the_rollouts_failed_in_train_on_from_their_hand_over_poses(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    results = [result(k, tmp_path) for k in range(4)]
    probe = evaluation(0.5, {"2": {"collision": 3}, "mission": {"rejected": 1}})
    jobs = repair_jobs(mission.training, results, probe, 1)
    assert [(job.subtask, job.round, job.folder(tmp_path)) for job in jobs] == [
        (2, 1, tmp_path / "subtask_2" / "handover_1")
    ]
    job = jobs[0]
    assert job.warm_start == tmp_path / "subtask_2"
    assert job.starts is not None
    assert [(p.position.tolist(), p.heading) for p in job.starts] == [
        ([1.0 + 0.1 * i, 2.0], 0.5 * i) for i in range(3)
    ]
    assert job.training.n_timesteps == mission.training.handover_steps
    assert job.training.env["curriculum"] == REPAIR_CURRICULUM
    assert job.seed != results[2].seed  # a repair explores anew
    again = SubtaskJob.from_json(job.to_json())
    assert again.starts is not None and (again.subtask, again.seed) == (job.subtask, job.seed)
    assert [p.position.tolist() for p in again.starts] == [p.position.tolist() for p in job.starts]
    assert again.to_json() == job.to_json()


def test_a_mission_curriculum_is_kept_in_repairs(plan: MissionPlan, tmp_path: Path) -> None:
    own = tiny_mission(env={"curriculum": 0.9})
    results = [result(k, tmp_path) for k in range(4)]
    jobs = repair_jobs(own.training, results, evaluation(0.0, {"0": {"timeout": 1}}), 1)
    assert jobs[0].training.env["curriculum"] == 0.9


def test_many_hand_over_poses_are_thinned_evenly() -> None:
    poses = [Pose(np.array([float(i), 0.0]), 0.0) for i in range(2 * MAX_STARTS + 1)]
    kept = start_poses(poses)
    assert len(kept) <= MAX_STARTS and kept[0].position.tolist() == [0.0, 0.0]
    assert len({float(p.position[0]) for p in kept}) == len(kept)
    assert len(start_poses(poses[:5])) == 5


def test_a_merged_result_counts_both_trainings(tmp_path: Path) -> None:
    before = result(1, tmp_path, steps=200)
    repair = TrainResult(
        subtask=1,
        seed=1011,
        model_path=str(tmp_path / "subtask_1" / "handover_1" / "model.zip"),
        steps=100,
        resumed_from=0,
        stopped="target",
        curve=[(100, 1.0)],
        final={"episodes": 2, "success_rate": 1.0},
        seconds=2.0,
    )
    after = merged(before, repair)
    assert (after.seed, after.steps, after.stopped, after.repairs) == (11, 300, "target", 1)
    assert after.curve == [(100, 0.0), (200, 0.5), (300, 1.0)]
    assert after.model_path == repair.model_path and after.final == repair.final
    assert after.seconds == 5.0 and merged(after, repair).repairs == 2


class ScriptedRun(MissionRun):
    """A run whose rollouts are scripted: the deciding evaluation after each round is the next
    of ``rates``; sub-task 1 always fails in the probe; the reported one (``finish``) is 0.25."""

    def __init__(self, mission: MissionSpec, plan: MissionPlan, folder: Path, rates: list[float]):
        super().__init__(mission, plan, folder)
        self.after = iter(rates)
        self.seeds: list[int] = []

    def evaluate(
        self, results: Sequence[TrainResult], seed: int | None = None
    ) -> MissionEvaluation:
        deciding = self.mission.training.seed + SELECTION_SEED
        self.seeds.append(deciding if seed is None else seed)
        if seed is None:
            return evaluation(next(self.after), {"1": {"collision": 1}})
        if seed == self.mission.training.seed + EVALUATION_SEED:
            return evaluation(0.25, {})
        return evaluation(0.0, {"1": {"collision": 1}})


def repair_rounds(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, rates: list[float]
) -> tuple[list[TrainResult], MissionEvaluation, list[RepairRound], list[int]]:
    """Repair with scripted rollouts (``ScriptedRun``) and jobs that finish at once."""
    run = ScriptedRun(mission, plan, tmp_path, rates)

    def train_all(batch: Sequence[SubtaskJob]) -> list[TrainResult]:
        return [
            TrainResult(
                job.subtask, job.seed, str(run.job_folder(job) / "model.zip"), 50, 0, "target"
            )
            for job in batch
        ]

    start = [result(k, tmp_path) for k in range(4)]
    results, final, rounds = run.repair(start, evaluation(0.5, {}), train_all)
    return results, final, rounds, run.seeds


def test_repair_rounds_are_kept_only_while_the_mission_improves(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    results, final, rounds, seeds = repair_rounds(mission, plan, tmp_path, [0.7, 0.6])
    assert [(r.round, r.subtasks, r.kept) for r in rounds] == [
        (1, [1], True),
        (2, [1], False),
    ]
    assert final.success_rate == 0.7 and results[1].repairs == 1
    assert results[1].model_path.endswith("handover_1/model.zip") and results[0].repairs == 0
    reported = mission.training.seed + EVALUATION_SEED
    assert reported not in seeds  # no decision used the reported rollouts' seed
    assert len(set(seeds[::2])) == 2 and mission.training.seed + SELECTION_SEED not in seeds[::2]


def test_finish_reports_rollouts_measured_after_every_decision(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import workers.bundle

    written: list[MissionEvaluation] = []

    def bundle(path: Path, *args: object) -> Path:
        written.append(args[3])  # type: ignore[arg-type]
        return path

    monkeypatch.setattr(workers.bundle, "write_bundle", bundle)
    run = ScriptedRun(mission, plan, tmp_path, [])
    results = [result(k, tmp_path) for k in range(4)]
    done = run.finish(results, evaluation(0.95, {}), [])
    assert run.seeds == [mission.training.seed + EVALUATION_SEED]
    assert done.evaluation.success_rate == 0.25 and written == [done.evaluation]
    record = json.loads((tmp_path / "handover_repair.json").read_text())
    assert record["mission_evaluation"]["success_rate"] == 0.25
    assert record["selection_evaluation"]["success_rate"] == 0.95


def test_repair_stops_at_the_mission_target(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    _, final, rounds, _ = repair_rounds(mission, plan, tmp_path, [0.95, 1.0])
    assert len(rounds) == 1 and final.success_rate == 0.95
    none = tiny_mission(handover_rounds=0)
    _, final, rounds, seeds = repair_rounds(none, plan, tmp_path, [1.0])
    assert rounds == [] and seeds == [] and final.success_rate == 0.5


def test_a_warm_started_job_trains_on_from_the_finished_policy_at_the_given_starts(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    first = tmp_path / "subtask_1"
    base = SubtaskJob(subtask=1, training=mission.training, seed=3)
    trained = train_subtask(mission, plan, base, first)
    starts = (Pose(np.array([3.3, 0.7]), 0.0),)
    training = TrainingSpec.model_validate({**mission.training.model_dump(), "n_timesteps": 100})
    repair = dataclasses.replace(
        base, training=training, starts=starts, warm_start=first, seed=9, round=1
    )
    assert repair.folder(tmp_path) == first / "handover_1"
    again = train_subtask(mission, plan, repair, first / "handover_1")
    assert (again.steps, again.resumed_from) == (100, 0)
    buffer = first / "handover_1" / "checkpoints" / "model_replay_buffer_100_steps.pkl"
    model = SAC.load(again.model_path, device="cpu")
    model.load_replay_buffer(buffer)
    assert model.replay_buffer is not None
    assert model.replay_buffer.size() == trained.steps + 100  # the first job's transitions too
    env = subtask_env(mission, plan, training, 1, True, starts)
    assert [p.position.tolist() for p in env.starts] == [[3.3, 0.7]]
    env.close()
    with pytest.raises(TrainingError, match=r"no model\.zip"):
        train_subtask(
            mission, plan, dataclasses.replace(repair, warm_start=tmp_path), tmp_path / "x"
        )


def test_explicit_starts_are_checked(mission: MissionSpec, plan: MissionPlan) -> None:
    with pytest.raises(EnvConfigError, match=r"starts\.0: must be a finite 2D point"):
        make_env(mission, 0, plan=plan, starts=[Pose(np.array([1.0, 2.0, 3.0]), 0.0)])
    with pytest.raises(EnvConfigError, match=r"starts\.1: .* outside the world bounds"):
        make_env(mission, 0, plan=plan, starts=[Pose(np.ones(2), 0.0), Pose(np.full(2, 9.0), 0)])
    with pytest.raises(EnvConfigError, match="no start pose"):
        make_env(mission, 0, plan=plan, starts=[])


def test_the_kept_results_merge_only_the_rounds_that_were_kept(tmp_path: Path) -> None:
    from workers.handover_repair import kept_results

    first = [result(k, tmp_path) for k in range(3)]

    def repaired(k: int, round_: int) -> TrainResult:
        path = str(tmp_path / f"subtask_{k}" / f"handover_{round_}" / "model.zip")
        return TrainResult(k, 100 + k, path, 50, 0, "target")

    rounds = [first, [repaired(1, 1)], [repaired(1, 2), repaired(2, 2)]]
    judged = [
        RepairRound(1, [1], 0.5, 0.7, True, 1.0),
        RepairRound(2, [1, 2], 0.7, 0.6, False, 1.0),
    ]
    kept = kept_results(rounds, judged)
    assert [r.repairs for r in kept] == [0, 1, 0]
    assert kept[1].model_path.endswith("handover_1/model.zip") and kept[1].steps == 250
    assert kept_results(rounds[:1], []) == first
