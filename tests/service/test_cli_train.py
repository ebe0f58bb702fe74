"""``ltlnav train`` and ``ltlnav rollout`` end to end on a tiny mission (real training)."""

from __future__ import annotations

import contextlib
import copy
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from service.cli import EXIT_BAD_INPUT, app
from tests.service.process_tree import cpu_ticks, descendants, running
from tests.workers.missions import TINY

runner = CliRunner()


def test_train_then_rollout(tmp_path: Path) -> None:
    mission = tmp_path / "mission.yaml"
    mission.write_text(yaml.safe_dump(copy.deepcopy(TINY)))
    out = tmp_path / "run"
    args = ["train", str(mission), "--out", str(out), "--jobs", "2", "--timesteps", "100"]
    result = runner.invoke(app, [*args, "--seed", "4", "--episodes", "2"])
    assert result.exit_code == 0, result.output
    assert "mission success rate" in result.output and "bundle written" in result.output
    for k in range(4):
        assert f"sub-task {k}: " in result.output
    subtask_lines = [line for line in result.output.splitlines() if "  sub-task " in line]
    assert len(subtask_lines) == 4
    assert all(" s (" in line and "learner and the rest" in line for line in subtask_lines)
    # 100 steps cannot train the mission: hand-over repair runs (handover_steps 200 in TINY)
    assert "hand-over repair 1 (sub-tasks" in result.output
    bundle = out / "bundle.zip"
    with zipfile.ZipFile(bundle) as archive:
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["seeds"]["training"] == 4 and manifest["seeds"]["subtasks"] == [4, 5, 6, 7]
    assert manifest["mission_evaluation"]["episodes"] == 2

    report, picture = tmp_path / "rollout.json", tmp_path / "rollout.png"
    result = runner.invoke(
        app,
        ["rollout", str(bundle), "--episodes", "2", "--json", str(report), "--plot", str(picture)],
    )
    assert result.exit_code == 0, result.output
    assert "success rate" in result.output
    data = json.loads(report.read_text())
    assert data["episodes"] == 2 and 0 <= data["success_rate"] <= 1
    assert {"collision_rate", "failures", "timeout_rate"} <= set(data)
    assert sum(sum(kinds.values()) for kinds in data["failures"].values()) == round(
        2 * (1 - data["success_rate"])
    )
    assert picture.read_bytes()[:4] == b"\x89PNG"

    again = runner.invoke(app, [*args, "--seed", "4", "--episodes", "2"])
    assert again.exit_code == 0, again.output  # resumes: every job returns its stored result


def test_legs_train_and_hand_over_at_their_joints(tmp_path: Path) -> None:
    """``planner.leg_length`` cuts the tiny mission's sub-tasks into legs, each trained as a
    sub-task (the point robot's controller meets them at step 0); the whole mission's
    rollouts cross every joint."""
    document = copy.deepcopy(TINY)
    document["planner"]["leg_length"] = 1.5
    document["training"]["env"] = {}  # the point robot's feed-forward, as by default
    mission = tmp_path / "mission.yaml"
    mission.write_text(yaml.safe_dump(document))
    out = tmp_path / "run"
    args = ["train", str(mission), "--out", str(out), "--jobs", "2", "--timesteps", "100"]
    result = runner.invoke(app, [*args, "--episodes", "4"])
    assert result.exit_code == 0, result.output
    with zipfile.ZipFile(out / "bundle.zip") as archive:
        manifest = json.loads(archive.read("manifest.json"))
    goals = [entry["goal"] for entry in manifest["subtasks"]]
    assert len(goals) > 4 and "" in goals and {"a", "b"} <= set(goals)
    assert all(entry["steps"] == 0 for entry in manifest["subtasks"])
    assert manifest["mission_evaluation"]["success_rate"] == 1.0


def test_rollout_refuses_a_foreign_zip(tmp_path: Path) -> None:
    foreign = tmp_path / "other.zip"
    with zipfile.ZipFile(foreign, "w") as archive:
        archive.writestr("hello.txt", "hi")
    result = runner.invoke(app, ["rollout", str(foreign), "--episodes", "1"])
    assert result.exit_code == EXIT_BAD_INPUT
    assert "not an ltlnav bundle" in result.output


def test_train_refuses_the_whole_lasso_mode(tmp_path: Path) -> None:
    data = copy.deepcopy(TINY)
    data["training"]["reward"] = {"mode": "g-rrt"}
    mission = tmp_path / "mission.yaml"
    mission.write_text(yaml.safe_dump(data))
    result = runner.invoke(app, ["train", str(mission), "--out", str(tmp_path / "run")])
    assert result.exit_code == EXIT_BAD_INPUT
    assert "g-rrt" in result.output and not (tmp_path / "run" / "plan.json").exists()


def test_train_reports_an_unknown_hyperparameter(tmp_path: Path) -> None:
    data = copy.deepcopy(TINY)
    data["training"]["hyperparams"]["gama"] = 0.9
    mission = tmp_path / "mission.yaml"
    mission.write_text(yaml.safe_dump(data))
    result = runner.invoke(app, ["train", str(mission), "--out", str(tmp_path / "run")])
    assert result.exit_code == EXIT_BAD_INPUT
    assert "training.hyperparams.gama" in result.output and "gamma" in result.output


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs Linux /proc")
def test_a_killed_train_leaves_no_worker_training(tmp_path: Path) -> None:
    """SIGKILL of ``ltlnav train`` mid-training: its pool's workers stop within seconds (after a
    checkpoint) and exit, instead of training on for nobody; the forkserver, the progress
    queue's manager and the resource tracker exit too."""
    mission = tmp_path / "mission.yaml"
    mission.write_text(yaml.safe_dump(copy.deepcopy(TINY)))
    out = tmp_path / "run"
    ltlnav = Path(sys.executable).parent / "ltlnav"
    args = [str(ltlnav), "train", str(mission), "--out", str(out), "--timesteps", "100000"]
    proc = subprocess.Popen(
        [*args, "--jobs", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    family: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("subtask_*/checkpoints")) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert proc.poll() is None, "ltlnav train ended before training"
        time.sleep(2)
        family = descendants(proc.pid)
        proc.kill()
        proc.wait()
        time.sleep(8)
        before = cpu_ticks(family)
        time.sleep(4)
        spent = cpu_ticks(family) - before
        assert spent <= 20, f"the orphans used {spent} CPU ticks in 4 s"  # 100 ticks a CPU-second
        assert len(family) >= 4  # the forkserver, the manager, two workers (and the tracker)
        assert running(family) == []
        assert list(out.glob("subtask_*/checkpoints/model_*_steps.zip"))  # it can resume
    finally:
        proc.kill()
        for pid in family:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
