"""The progress bars of ``ltlnav train``: time left while a sub-task trains, the time it took
once it is done, even far below its budget."""

from __future__ import annotations

from service.train_progress import RemainingOrElapsed, TrainProgress, how_stopped
from workers.train_result import TrainResult


def test_a_sub_task_done_at_its_target_shows_how_long_it_ran() -> None:
    bars = TrainProgress()
    column = RemainingOrElapsed()
    bars.show(0, 0, None, 150_000, False)
    bars.show(0, 10_000, 1.0, 150_000, False)
    running = bars.progress.tasks[0]
    assert not column.render(running).plain.startswith("done")
    bars.show(0, 10_000, 1.0, 150_000, True)
    done = bars.progress.tasks[0]
    assert column.render(done).plain.startswith("done in ")
    assert done.fields["success"] == "100 %" and done.completed == 10_000
    assert done.fields["took"] is not None
    bars.show(0, 12_000, 0.5, 180_000, False)  # a repair round trains it again
    assert not column.render(bars.progress.tasks[0]).plain.startswith("done")


def test_a_sub_task_whose_training_ended_shows_the_evaluation_it_runs() -> None:
    bars = TrainProgress()
    column = RemainingOrElapsed()
    bars.show(0, 65_000, 0.88, 150_000, False)
    bars.evaluating(0, "picking the kept policy: 2 of 4")
    assert column.render(bars.progress.tasks[0]).plain == "picking the kept policy: 2 of 4"
    bars.show(0, 65_000, 0.88, 150_000, False)  # the job's last progress, after its evaluations
    assert column.render(bars.progress.tasks[0]).plain == "picking the kept policy: 2 of 4"
    bars.show(0, 65_000, 0.88, 150_000, True)
    assert column.render(bars.progress.tasks[0]).plain.startswith("done in ")
    bars.show(0, 65_000, 0.88, 95_000, False)  # a repair round starts where it ended
    assert column.render(bars.progress.tasks[0]).plain != "picking the kept policy: 2 of 4"
    bars.evaluating(7, "final evaluation: 200 trials")  # no bar of its own: ignored


def test_the_result_names_the_kept_policy_and_how_it_was_picked() -> None:
    result = TrainResult(
        subtask=0, seed=0, model_path="m.zip", steps=150_000, resumed_from=0, stopped="budget"
    )
    assert how_stopped(result) == "budget"
    result.policy_steps = 130_000
    assert how_stopped(result) == "budget; policy of step 130000, its best evaluation"
    result.selection = [(0, 0.81, 200), (130_000, 0.905, 200), (150_000, 0.6, 40)]
    assert how_stopped(result) == (
        "budget; policy of step 130000, the pick's best of 3: 90.5 % of 200 trials"
    )
