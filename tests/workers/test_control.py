"""The zero-action control is measured exactly as a job reports the policy that the controller
alone makes: the same episodes from the same starts."""

from __future__ import annotations

from pathlib import Path

from workers.control import zero_control
from workers.jobs import SubtaskJob, job_seed
from workers.run import stored_or_new_plan
from workers.training import train_subtask

from .missions import tiny_mission


def test_the_control_equals_the_report_of_a_job_stopped_at_step_0(tmp_path: Path) -> None:
    mission = tiny_mission(env={"guide_feedforward": 1.0}, n_timesteps=200, final_eval_episodes=6)
    document = mission.model_dump(mode="json")
    document["robot"] = {"model": "unicycle", "start": [0.5, 0.5], "radius": 0.05}
    mission = type(mission).model_validate(document)
    plan = stored_or_new_plan(mission, tmp_path / "plan")
    last = len(plan.subtasks) - 1  # a job seed other than training.seed
    assert last > 0
    job = SubtaskJob(last, mission.training, seed=job_seed(mission.training, last))
    result = train_subtask(mission, plan, job, tmp_path / "job")
    assert (result.steps, result.stopped) == (0, "target")  # the controller alone
    control = zero_control(mission, plan)
    assert len(control.subtasks) == len(plan.subtasks)
    assert control.subtasks[last].to_json() == result.final
    assert control.subtasks[last].episodes == 6
    assert control.mission.episodes == mission.training.mission_episodes
