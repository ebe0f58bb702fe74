"""Where a job's wall time goes: each part counts its own time only, the parts add up to the
job's wall time, and a repaired sub-task's parts are those of both calls."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from planner.plan import MissionPlan
from workers.callbacks import ResumableEvalCallback
from workers.evaluation import SubtaskEvaluation
from workers.handover_repair import merged
from workers.jobs import SubtaskJob
from workers.mission import MissionSpec
from workers.stopwatch import LEARNER, Stopwatch
from workers.train_result import TrainResult
from workers.training import train_subtask
from workers.training_spec import TrainingSpec


def test_a_part_timed_inside_another_counts_for_itself_only() -> None:
    watch = Stopwatch()
    with watch.part("outer"):
        time.sleep(0.05)
        with watch.part("inner"):
            time.sleep(0.1)
    with watch.part("inner"):
        time.sleep(0.05)
    assert 0.05 <= watch.seconds["outer"] < 0.1
    assert 0.15 <= watch.seconds["inner"] < 0.2
    parts = watch.split(1.0)
    assert sum(parts.values()) == pytest.approx(1.0, abs=0.01)
    assert parts[LEARNER] == pytest.approx(1.0 - 0.2, abs=0.05)


def test_a_jobs_parts_add_up_to_its_wall_time_and_confirmations_are_their_own(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every periodic evaluation reaches the target; the confirmations (each 0.5 s, asked
    from inside a periodic evaluation) fail once and then pass; the final evaluation takes
    0.1 s. Periodic evaluations of the tiny mission take about 0.05 s each."""
    import workers.training as training_module

    durations = iter([(0.5, 0.0), (0.5, 1.0), (0.1, 0.3)])

    def scripted(
        act: Any, envs: Any, episodes: int, seed: int, needed: int = 0
    ) -> SubtaskEvaluation:
        seconds, rate = next(durations)
        time.sleep(seconds)
        return SubtaskEvaluation(episodes, rate, 0.0, 0.0, None)

    monkeypatch.setattr(training_module, "evaluate_subtask", scripted)
    monkeypatch.setattr(ResumableEvalCallback, "last_success_rate", property(lambda _: 1.0))
    training = TrainingSpec.model_validate(
        {**mission.training.model_dump(), "n_timesteps": 400, "eval_freq": 100}
    )
    result = train_subtask(mission, plan, SubtaskJob(0, training, seed=3), tmp_path)
    assert result.stopped == "target" and len(result.confirmations) == 2
    parts = result.parts
    assert {"periodic evaluations", "confirmations", "final evaluation", "checkpoints"} <= set(
        parts
    )
    assert 1.0 <= parts["confirmations"] < 1.2
    assert 0.1 <= parts["final evaluation"] < 0.2
    assert 0 < parts["periodic evaluations"] < 0.5  # without the confirmations inside them
    assert sum(parts.values()) == pytest.approx(result.seconds, abs=0.01)
    assert TrainResult.from_json(result.to_json()).parts == parts


def test_a_repaired_sub_task_counts_the_parts_of_both_calls() -> None:
    before = TrainResult(0, 1, "a.zip", 100, 0, "budget", seconds=3.0, parts={"x": 1.0, "y": 2.0})
    repair = TrainResult(0, 2, "b.zip", 50, 0, "target", seconds=2.0, parts={"y": 1.5, "z": 0.5})
    both = merged(before, repair)
    assert both.seconds == 5.0
    assert both.parts == {"x": 1.0, "y": 3.5, "z": 0.5}
