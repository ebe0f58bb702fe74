"""The pick of the kept policy (``training.pick_candidates``): the store of the best
evaluations' policies, the pick itself, and a job that picks on seeds of their own."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from stable_baselines3 import SAC

from planner.plan import MissionPlan
from workers.callbacks import ResumableEvalCallback
from workers.candidates import Candidate, CandidateStore
from workers.evaluation import SubtaskEvaluation
from workers.hooks import TrainingHooks
from workers.jobs import SubtaskJob
from workers.mission import MissionError, MissionSpec
from workers.policy_pick import pick_policy
from workers.training import train_subtask
from workers.training_spec import TrainingSpec

from .missions import tiny_mission


def saver(text: str) -> Any:
    return lambda path: Path(path).write_text(text)


def test_the_store_keeps_the_best_first_the_earlier_on_a_tie_and_only_their_files(
    tmp_path: Path,
) -> None:
    store = CandidateStore(tmp_path, keep=2)
    for steps, rate in [(0, 0.5), (5, 0.9), (10, 0.7), (15, 0.9), (20, 0.9)]:
        store.add(steps, rate, saver(f"policy {steps}"))
    assert [(c.steps, c.success_rate) for c in store.ranked()] == [(5, 0.9), (15, 0.9)]
    assert sorted(p.name for p in tmp_path.glob("policy_*.zip")) == [
        "policy_15.zip",
        "policy_5.zip",
    ]
    assert not store.wanted(25, 0.9) and store.wanted(25, 0.95) and not store.wanted(5, 1.0)
    again = CandidateStore(tmp_path, keep=2)
    assert again.ranked() == store.ranked()
    assert again.ranked()[0].path.read_text() == "policy 5"
    again.restore(upto=10)  # a job resumed from step 10 redoes step 15
    assert [c.steps for c in again.ranked()] == [5]
    assert not (tmp_path / "policy_15.zip").exists()
    (tmp_path / "policy_5.zip").unlink()  # the index never names a file that is not there
    assert CandidateStore(tmp_path, keep=2).ranked() == []


def evaluation(rate: float, episodes: int = 20) -> SubtaskEvaluation:
    return SubtaskEvaluation(episodes, rate, 0.0, 0.0, None)


def test_the_pick_keeps_most_successes_and_stops_a_candidate_that_cannot_win(
    tmp_path: Path,
) -> None:
    candidates = [Candidate(s, r, tmp_path / f"policy_{s}.zip") for s, r in [(5, 0.92), (9, 0.9)]]
    measured = {"policy_5": evaluation(0.8), "policy_9": evaluation(0.9)}
    measured["last"] = evaluation(0.5, 4)
    asked: list[tuple[str, int]] = []

    def evaluate(policy: str, needed: int) -> SubtaskEvaluation:
        asked.append((policy, needed))
        return measured[policy]

    kept, steps, trials = pick_policy("last", 12, candidates, lambda p: p.stem, evaluate)
    assert (kept, steps) == ("policy_9", 9)
    assert asked == [("policy_5", 0), ("policy_9", 17), ("last", 19)]
    assert trials == [(5, 0.8, 20), (9, 0.9, 20), (12, 0.5, 4)]
    measured["last"] = evaluation(0.8)  # a tie with the first: the earlier stays
    assert pick_policy("last", 12, candidates[:1], lambda p: p.stem, evaluate)[:2] == (
        "policy_5",
        5,
    )
    kept, steps, trials = pick_policy("last", 5, candidates[:1], lambda p: p.stem, evaluate)
    assert (kept, steps, [t[0] for t in trials]) == ("last", None, [5])  # the same policy once


class SaysWhatItEvaluates(TrainingHooks):
    def __init__(self) -> None:
        self.said: list[str] = []

    def evaluating(self, what: str) -> None:
        self.said.append(what)


def test_a_job_picks_its_kept_policy_on_seeds_of_their_own(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Periodic evaluations make 0.5, 0.9, 0.8, 0.6: the policies of steps 200 and 300 are the
    candidates. On the selection seed step 300's makes most successes and is kept although
    step 200's periodic rate was higher; the last policy's trial stops once it cannot win.
    The job says which evaluation it runs once its training has ended."""
    import workers.training as training_module

    periodic = [0.5, 0.9, 0.8, 0.6]
    monkeypatch.setattr(
        ResumableEvalCallback,
        "last_success_rate",
        property(lambda self: periodic[len(self.evaluations_successes) - 1]),
    )
    spec = TrainingSpec.model_validate(
        {
            **mission.training.model_dump(),
            "n_timesteps": 400,
            "eval_freq": 100,
            "final_eval_episodes": 20,
            "target_success": 1.0,
            "pick_candidates": 2,
        }
    )
    job = SubtaskJob(subtask=0, training=spec, seed=3)
    selection_seed = job.seed + training_module.SELECTION_SEED
    picked = iter([evaluation(0.6), evaluation(0.9), evaluation(0.5, 4)])
    asked: list[tuple[int, int]] = []

    def scripted(
        act: Any, envs: Any, episodes: int, seed: int, needed: int = 0
    ) -> SubtaskEvaluation:
        asked.append((seed, needed))
        return next(picked) if seed == selection_seed else evaluation(0.0, episodes)

    monkeypatch.setattr(training_module, "evaluate_subtask", scripted)
    hooks = SaysWhatItEvaluates()
    result = train_subtask(mission, plan, job, tmp_path, hooks)
    assert result.stopped == "budget" and result.policy_steps == 300
    assert result.selection == [(200, 0.6, 20), (300, 0.9, 20), (400, 0.5, 4)]
    assert [needed for seed, needed in asked if seed == selection_seed] == [0, 13, 19]
    assert asked[-1][0] == job.seed + training_module.REPORT_SEED  # reported after the pick
    assert SAC.load(tmp_path / "model.zip", device="cpu").num_timesteps == 300
    assert sorted(p.name for p in (tmp_path / "candidates").glob("*.zip")) == [
        "policy_200.zip",
        "policy_300.zip",
    ]
    assert "pick" in result.parts
    assert hooks.said == [
        "picking the kept policy: 1 of 3",
        "picking the kept policy: 2 of 3",
        "picking the kept policy: 3 of 3",
        "final evaluation: 20 trials",
    ]
    assert not (tmp_path / "best_model.zip").exists()  # the pick's store holds the best


def test_pick_candidates_must_be_positive() -> None:
    with pytest.raises(MissionError, match=r"training\.pick_candidates"):
        tiny_mission(pick_candidates=0)
