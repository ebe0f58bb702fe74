"""``ltlnav submit`` against a served app (uvicorn in a thread) whose enqueue starts a fake
worker thread; ``ltlnav serve`` as a real process, stopped by SIGINT and SIGTERM."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from typer.testing import CliRunner

from service.api.app import create_app
from service.cli import app as cli
from service.db import Database, upgrade
from service.models import MissionStatus
from service.progress_printer import ProgressPrinter
from service.settings import Settings
from tests.service.api_helpers import REPO, advance, free_port, served, settings_for, tiny
from tests.service.process_tree import descendants, running
from workers.bundle_reader import read_bundle


class FakeWorker:
    """An enqueue that drives each mission to ``outcome`` in a thread, as the workers would."""

    def __init__(self, database: Database, artifacts: Path, outcome: MissionStatus) -> None:
        self.database, self.artifacts, self.outcome = database, artifacts, outcome
        self.threads: list[threading.Thread] = []

    def __call__(self, mission_id: str) -> None:
        def run() -> None:
            first = MissionStatus.training
            if self.outcome == MissionStatus.failed:
                first = MissionStatus.planning
            time.sleep(0.2)
            advance(self.database, mission_id, self.artifacts, first)
            time.sleep(0.5)
            advance(self.database, mission_id, self.artifacts, self.outcome)

        thread = threading.Thread(target=run)
        thread.start()
        self.threads.append(thread)


@pytest.fixture
def stack(sqlite_url: str, tmp_path: Path) -> Iterator[tuple[Database, Settings]]:
    upgrade(sqlite_url)
    database = Database(sqlite_url)
    yield database, settings_for(tmp_path, sqlite_url, keys=["k1"])
    database.dispose()


def _mission_file(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(tiny()))
    return path


@pytest.mark.timeout(60)
@pytest.mark.parametrize("outcome", [MissionStatus.done, MissionStatus.failed])
def test_submit_wait_downloads_the_bundle_or_fails(
    stack: tuple[Database, Settings], tmp_path: Path, outcome: MissionStatus
) -> None:
    database, settings = stack
    worker = FakeWorker(database, settings.artifact_dir, outcome)
    out = tmp_path / "out"
    with served(create_app(settings, worker)) as base:
        args = ["submit", str(_mission_file(tmp_path)), "--url", base, "--api-key", "k1"]
        result = CliRunner().invoke(cli, [*args, "--wait", "--poll", "0.1", "--out", str(out)])
    for thread in worker.threads:
        thread.join()
    if outcome == MissionStatus.done:
        assert result.exit_code == 0, result.output
        assert "status: training" in result.output
        assert "sub-task 0:" in result.output
        assert "mission success rate 100.0 % over 2 rollouts" in result.output
        with zipfile.ZipFile(out / "bundle.zip") as archive:
            assert archive.namelist() == ["manifest.json"]
    else:
        assert result.exit_code == 1, result.output
        assert "mission failed: no plan: unsatisfiable" in result.output
        assert not (out / "bundle.zip").exists()


def test_the_progress_shows_each_repair_round_and_job_once(
    capsys: pytest.CaptureFixture[str],
) -> None:
    show = ProgressPrinter()
    news = "hand-over repair round 1: mission success 40 %, below its target; sub-task(s) 1, 2"
    job = {"index": 1, "status": "done", "steps_done": 100, "budget": 100, "success_rate": 0.5}
    repair = {**job, "round": 1, "status": "running", "steps_done": 0, "budget": 30000}
    for steps in (0, 1000, 5000):
        repair = {**repair, "steps_done": steps, "success_rate": 0.4 if steps else None}
        show({"status": "training", "reason": news, "jobs": [job], "repairs": [repair]})
    show({"status": "failed", "reason": "assembly: boom", "jobs": [job], "repairs": []})
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        "status: training",
        f"  {news}",
        "  sub-task 1: done, 100/100 steps, success 50 %",
        "  repair 1 of sub-task 1: running, 0/30000 steps, success -",
        "  repair 1 of sub-task 1: running, 5000/30000 steps, success 40 %",
        "status: failed",
    ]


def test_the_progress_names_each_evaluation_a_job_runs_after_its_training(
    capsys: pytest.CaptureFixture[str],
) -> None:
    show = ProgressPrinter()
    job = {"index": 0, "status": "running", "steps_done": 65000, "budget": 150000}
    job = {**job, "success_rate": 0.88, "eta_seconds": 700.0, "reason": None}
    show({"status": "training", "jobs": [job]})
    for what in ("picking the kept policy: 1 of 4", "picking the kept policy: 2 of 4"):
        show({"status": "training", "jobs": [{**job, "eta_seconds": None, "reason": what}]})
        show({"status": "training", "jobs": [{**job, "eta_seconds": None, "reason": what}]})
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        "status: training",
        "  sub-task 0: running, 65000/150000 steps, success 88 %, ETA 700 s",
        "  sub-task 0: running, 65000/150000 steps, success 88 %, picking the kept policy: 1 of 4",
        "  sub-task 0: running, 65000/150000 steps, success 88 %, picking the kept policy: 2 of 4",
    ]


def test_submit_reports_problems_and_bad_keys(
    stack: tuple[Database, Settings], tmp_path: Path
) -> None:
    _, settings = stack
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ntask: '[]<>a &&'\nworld: {bounds: [[0, 1], [0, 1]]}\n")
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [\n")
    calls: list[str] = []
    runner = CliRunner()
    with served(create_app(settings, calls.append)) as base:
        invalid = runner.invoke(cli, ["submit", str(bad), "--url", base, "--api-key", "k1"])
        denied = runner.invoke(cli, ["submit", str(bad), "--url", base, "--api-key", "nope"])
        example = runner.invoke(cli, ["submit", "tlrrt-gf3", "--url", base, "--api-key", "k1"])
    syntax = runner.invoke(cli, ["submit", str(broken), "--url", "http://127.0.0.1:9"])
    unreachable = runner.invoke(
        cli, ["submit", str(bad), "--url", f"http://127.0.0.1:{free_port()}"]
    )
    assert invalid.exit_code == 2
    assert "422" in invalid.output and "task: column 9" in invalid.output
    assert denied.exit_code == 2 and "401" in denied.output
    assert example.exit_code == 0, example.output
    assert len(calls) == 1 and calls[0] in example.output
    assert syntax.exit_code == 2 and "invalid YAML at line" in syntax.output
    assert unreachable.exit_code == 1 and "cannot reach the service" in unreachable.output


def _serve(tmp_path: Path, port: int, *extra: str) -> subprocess.Popen[str]:
    env = {**os.environ, "LTLNAV_DATA_DIR": str(tmp_path / "data")}
    for name in ("LTLNAV_API_KEYS", "DATABASE_URL", "LTLNAV_DATABASE_URL", "LTLNAV_BROKER_URL"):
        env.pop(name, None)
    command = [sys.executable, "-m", "service.cli", "serve", "--port", str(port), *extra]
    return subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def _stopped(process: subprocess.Popen[str], stop: signal.Signals) -> str:
    """Send ``stop`` and wait for the process to exit; its output."""
    process.send_signal(stop)
    output, _ = process.communicate(timeout=60)
    return output


def _wait_healthy(base: str, process: subprocess.Popen[str], seconds: float = 60) -> dict[str, str]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()[0]
        try:
            report: dict[str, str] = httpx.get(f"{base}/healthz", timeout=2).json()
            return report
        except httpx.HTTPError:
            time.sleep(0.2)
    raise AssertionError("ltlnav serve did not answer")


def _every_process_healthy(
    base: str, process: subprocess.Popen[str], in_a_row: int = 20, seconds: float = 60
) -> None:
    """Wait until ``in_a_row`` health checks, each on a new connection (spread over the API
    processes by the kernel), answer 200 one after the other: every process has finished
    its start-up probe and found the database and the broker."""
    deadline = time.monotonic() + seconds
    healthy = 0
    while healthy < in_a_row:
        assert process.poll() is None, process.communicate()[0]
        with httpx.Client() as client:
            answer = client.get(f"{base}/healthz", timeout=5)
        if answer.status_code == 200:
            healthy += 1
            continue
        assert time.monotonic() < deadline, f"not every process is healthy: {answer.text}"
        healthy = 0
        time.sleep(0.2)


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_serve_migrates_says_open_and_stops_cleanly(tmp_path: Path, stop: signal.Signals) -> None:
    port = free_port()
    process = _serve(tmp_path, port, "--workers", "1")
    try:
        report = _wait_healthy(f"http://127.0.0.1:{port}", process)
        assert report["database"] == "ok" and report["open"]
        time.sleep(1)
        output = _stopped(process, stop)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, output
    assert "the API is open" in output
    assert f"dashboard: http://127.0.0.1:{port}/" in output
    assert "worker started" in output
    assert "worker stopped" in output
    assert (tmp_path / "data" / "ltlnav.db").is_file()
    worker_pid = re.search(r"worker started \(pid (\d+)", output)
    assert worker_pid is not None
    # The worker led its own session: nothing of it (pool processes included) is left.
    session = subprocess.run(["pgrep", "-s", worker_pid.group(1)], capture_output=True, text=True)
    assert session.stdout == ""


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_serve_then_submit_wait_trains_the_tiny_mission(tmp_path: Path) -> None:
    """The product path: ``ltlnav serve`` (API + embedded worker) and ``ltlnav submit --wait``
    as real processes; the bundle downloaded opens."""
    port = free_port()
    process = _serve(tmp_path, port, "--workers", "2")
    base = f"http://127.0.0.1:{port}"
    try:
        _wait_healthy(base, process)
        out = tmp_path / "out"
        mission = str(_mission_file(tmp_path))
        options = ["--url", base, "--wait", "--poll", "0.5", "--out", str(out)]
        submit = subprocess.run(
            [sys.executable, "-m", "service.cli", "submit", mission, *options],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=240,
        )
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
    assert submit.returncode == 0, submit.stdout + submit.stderr
    assert "status: done" in submit.stdout
    assert "mission success rate" in submit.stdout
    manifest, files = read_bundle(out / "bundle.zip")
    assert len(manifest.subtasks) == 4 and files


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_serve_runs_the_api_in_several_processes_and_stops_them_all(tmp_path: Path) -> None:
    port = free_port()
    process = _serve(tmp_path, port, "--no-worker", "--api-processes", "2")
    base = f"http://127.0.0.1:{port}"
    try:
        _wait_healthy(base, process)
        _every_process_healthy(base, process)
        children = descendants(process.pid)
        assert len(children) >= 2
        output = _stopped(process, signal.SIGTERM)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, output
    assert "API in 2 processes" in output
    assert output.count("Application startup complete") == 2, output
    # The API processes and multiprocessing's resource tracker exit with the supervisor.
    deadline = time.monotonic() + 10
    while running(children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert running(children) == []
