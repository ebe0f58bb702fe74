"""Table I's records (``bench/table1.py``): a finished run's figures are kept as small JSON, and
the table and its figures are printed from them once the run folders are gone."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import table1  # noqa: E402

TASK = table1.TASKS[0]


def finished_run(out: Path, method: str, protocol: str) -> None:
    """A run folder as ``table1.train`` leaves it: plan, per sub-task result and periodic
    evaluations, and the measured wall time (no bundle: the mission was not assembled)."""
    folder = out / table1.run_row(TASK, method, protocol, 0).folder
    plan: dict[str, Any] = {"plan": {"subtasks": [{}, {}]}}
    folder.mkdir(parents=True)
    (folder / "plan.json").write_text(json.dumps(plan))
    for k, (rate, steps, stopped) in enumerate(((0.97, 5000, "target"), (0.4, 30000, "budget"))):
        job = folder / f"subtask_{k}"
        job.mkdir()
        result = {
            "steps": steps,
            "stopped": stopped,
            "seconds": 60.0,
            "final": {"success_rate": rate},
        }
        (job / "result.json").write_text(json.dumps(result))
        successes = np.array([[0, 0, 1, 1], [1, 1, 1, 1]]) if k == 0 else np.zeros((3, 4))
        timesteps = np.arange(1, len(successes) + 1) * 5000
        np.savez(job / "evaluations.npz", timesteps=timesteps, successes=successes)
    (folder / "wall.json").write_text(json.dumps({"seconds": 300.0, "jobs": 2, "commit": "abc"}))


def test_a_finished_run_is_reported_from_its_record_after_its_folder_is_deleted(
    tmp_path: Path,
) -> None:
    out, records = tmp_path / "runs", tmp_path / "records"
    finished_run(out, "rrt", "shaped")

    table = table1.report([TASK], ["rrt", "ned"], ["shaped"], [0], out, records)
    shutil.rmtree(out)
    again = table1.report([TASK], ["rrt", "ned"], ["shaped"], [0], out, records)

    assert again == table
    rrt = next(line for line in table.splitlines() if "| rrt |" in line)
    assert "| 68 % (40 %) |" in rrt  # median of 97 % and 40 %, worst 40 %
    assert "| 18k |" in rrt and "| 5.0 min |" in rrt and "| 1 of 2 |" in rrt
    ned = next(line for line in table.splitlines() if "| ned |" in line)
    assert "not run" in ned
    record = json.loads(next(records.rglob("seed0.json")).read_text())
    assert record["commit"] == "abc" and record["jobs"] == 2
    assert record["curve"]["subtask_0"] == {"timesteps": [5000, 10000], "success": [0.5, 1.0]}
    assert record["curve"]["subtask_1"]["success"] == [0.0, 0.0, 0.0]


def test_an_unfinished_run_leaves_no_record(tmp_path: Path) -> None:
    out, records = tmp_path / "runs", tmp_path / "records"
    finished_run(out, "tl", "paper")
    (out / table1.run_row(TASK, "tl", "paper", 0).folder / "wall.json").unlink()

    assert table1.run_figures(TASK, "tl", "paper", 0, out, records) == {}
    assert not records.exists()


def test_the_figure_is_drawn_from_the_records_alone(tmp_path: Path) -> None:
    out, records = tmp_path / "runs", tmp_path / "records"
    finished_run(out, "rrt", "paper")
    table1.run_figures(TASK, "rrt", "paper", 0, out, records)
    shutil.rmtree(out)

    curve = table1.method_curve(TASK, "rrt", "paper", [0], out, records)
    picture = tmp_path / "row.png"
    table1.curves(TASK, ["rrt", "ned"], "paper", [0], out, records, picture)

    assert curve is not None
    steps, grid = curve
    assert steps.tolist() == [5000, 10000, 15000]
    assert grid.tolist() == [[0.5, 1.0, 1.0], [0.0, 0.0, 0.0]]  # sub-task 0 stopped at 10k
    assert table1.method_curve(TASK, "ned", "paper", [0], out, records) is None
    assert picture.read_bytes().startswith(b"\x89PNG")


def test_a_run_with_a_record_is_not_trained_again_where_its_folder_is_gone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out, records = tmp_path / "runs", tmp_path / "records"
    finished_run(out, "rrt", "shaped")
    table1.run_figures(TASK, "rrt", "shaped", 0, out, records)
    shutil.rmtree(out)
    trained: list[str] = []

    def run_rows(rows: list[table1.Row], out: Path, jobs: int) -> None:
        trained.extend(row.method for row in rows)
        (out / rows[0].folder).mkdir(parents=True)

    monkeypatch.setattr(table1, "run_rows", run_rows)

    table1.train(TASK, "rrt", "shaped", 0, out, records, jobs=2)
    table1.train(TASK, "tl", "shaped", 0, out, records, jobs=2)

    assert trained == ["tl"]  # the one without a record


def test_its_runs_keep_one_budget_whatever_the_stop_defaults() -> None:
    from train import load_mission

    task = next(t for t in table1.TASKS if t.name == "car-phi2-fin")
    row = table1.run_row(task, "ned", "paper", 1)
    assert row.folder == "car-phi2-fin/ned+handover_rounds=0+protocol=paper/seed1"
    training = load_mission(task.name, row).training
    assert training.plateau_evals is None and training.pick_candidates is None
    assert training.n_timesteps == task.budget and training.handover_rounds == 0
