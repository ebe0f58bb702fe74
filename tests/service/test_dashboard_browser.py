"""The dashboard in a real headless Chromium (Debian's, driven by Playwright; never downloaded).

Quick tests run the real API in a thread with a recording ``enqueue`` (no worker); the slow
one starts ``ltlnav serve`` (API + embedded Celery worker, SQLite + embedded broker) and takes
a tiny example mission from the submit form to the downloaded bundle.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn

from service.db import upgrade
from service.settings import Settings
from tests.workers.missions import TINY

CHROMIUM = Path("/usr/bin/chromium")
if not CHROMIUM.is_file():
    pytest.skip(
        f"{CHROMIUM} is missing (Debian package chromium; `make browser` installs it)",
        allow_module_level=True,
    )
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")

CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
EXAMPLE = "tiny"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def write_example(folder: Path, **training: Any) -> None:
    """The tiny mission as the only example, named ``EXAMPLE``."""
    document = json.loads(json.dumps(TINY))
    document["training"].update(training)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{EXAMPLE}.json").write_text(json.dumps(document))


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(accept_downloads=True)
    page = context.new_page()
    page.set_default_timeout(15_000)
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        yield page
    finally:
        context.close()
    assert errors == [], f"JavaScript errors on the page: {errors}"


class ThreadServer:
    """The real API app under uvicorn in a thread of the test process."""

    def __init__(self, settings: Settings, enqueue: Any) -> None:
        from service.api.app import create_app

        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(
            create_app(settings, enqueue=enqueue), port=self.port, log_level="warning"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> ThreadServer:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)
        return self

    def __exit__(self, *_: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)


def quick_settings(tmp_path: Path, **extra: Any) -> Settings:
    examples = tmp_path / "examples"
    write_example(examples)
    settings = Settings(data_dir=tmp_path / "data", examples_dir=examples, **extra)
    settings.make_dirs()
    upgrade(settings.database_url)
    return settings


@pytest.mark.timeout(120)
def test_submit_cancel_list_and_bad_submissions_show_the_api_error(
    tmp_path: Path, page: Any
) -> None:
    sent: list[str] = []
    with ThreadServer(quick_settings(tmp_path), sent.append) as server:
        page.goto(server.url + "/")
        page.wait_for_selector("#no-missions")
        assert page.locator("#example option").first.get_attribute("value") == EXAMPLE

        page.select_option("#example", "")
        page.fill("#mission-json", "{not json")
        page.click("#submit")
        page.wait_for_selector("#submit-error:has-text('mission JSON')")

        bad = json.loads(json.dumps(TINY))
        bad["task"] = "[]<>a && ("
        page.fill("#mission-json", json.dumps(bad))
        page.click("#submit")
        message = page.locator("#submit-error")
        message.filter(has_text="422").wait_for()
        assert "task" in message.inner_text()
        assert sent == []

        page.select_option("#example", EXAMPLE)
        page.click("#submit")
        page.wait_for_url("**/#/missions/*")
        mission_id = page.url.rsplit("/", 1)[1]
        page.wait_for_selector("#mission-status .badge.queued")
        assert page.is_disabled("#download")
        assert sent == [mission_id]

        page.click("#cancel")
        page.wait_for_selector("#mission-status .badge.cancelled")
        assert page.is_disabled("#cancel")

        page.click("text=← all missions")
        row = page.locator("#missions tbody tr")
        row.first.wait_for()
        assert row.count() == 1
        assert TINY["name"] in row.first.inner_text()
        assert "cancelled" in row.first.locator(".badge").inner_text()


@pytest.mark.timeout(120)
def test_missions_list_pages(tmp_path: Path, page: Any) -> None:
    unlimited = {"quota_active_missions": 0, "quota_submissions_per_minute": 0}  # 51 posts
    with ThreadServer(quick_settings(tmp_path, **unlimited), lambda _id: None) as server:
        with httpx.Client(base_url=server.url) as client:
            for _ in range(51):
                client.post("/missions", json={"example": EXAMPLE}).raise_for_status()
        page.goto(server.url + "/")
        pager = page.locator("nav[aria-label='Mission pages']")
        pager.filter(has_text="1–50 of 51").wait_for()
        assert page.locator("#missions tbody tr").count() == 50
        pager.get_by_text("older →").click()
        pager.filter(has_text="51–51 of 51").wait_for()
        assert page.locator("#missions tbody tr").count() == 1
        pager.get_by_text("← newer").click()
        pager.filter(has_text="1–50 of 51").wait_for()


@contextmanager
def example_submitted(tmp_path: Path, page: Any, on_submit: Any) -> Iterator[None]:
    """The example submitted from the dashboard to the real API, whose ``enqueue`` calls
    ``on_submit(session, mission_id)`` in a database session of its own (no worker)."""
    from service.db import Database

    settings = quick_settings(tmp_path)
    database = Database(settings.database_url)

    def enqueue(mission_id: str) -> None:
        with database.session() as session:
            on_submit(session, mission_id)

    try:
        with ThreadServer(settings, enqueue) as server:
            page.goto(server.url + "/")
            page.select_option("#example", EXAMPLE)
            page.click("#submit")
            yield
    finally:
        database.dispose()


@pytest.mark.timeout(120)
def test_a_failed_mission_shows_its_reason(tmp_path: Path, page: Any) -> None:
    from service import repository
    from service.models import MissionStatus

    reason = "infeasible: region 'b' cannot be reached"

    def fail(session: Any, mission_id: str) -> None:
        repository.set_status(session, mission_id, MissionStatus.failed, reason=reason)

    with example_submitted(tmp_path, page, fail):
        page.wait_for_selector("#mission-status .badge.failed")
        assert page.inner_text("#mission-reason") == reason
        assert page.is_disabled("#cancel") and page.is_disabled("#download")
        page.click("text=← all missions")
        page.locator("#missions .reason").filter(has_text=reason).wait_for()


@pytest.mark.timeout(120)
def test_a_job_whose_training_ended_shows_the_evaluation_it_runs(tmp_path: Path, page: Any) -> None:
    from service import repository
    from service.models import MissionStatus

    what = "picking the kept policy: 2 of 4"

    def train(session: Any, mission_id: str) -> None:
        for status in (MissionStatus.planning, MissionStatus.training):
            repository.set_status(session, mission_id, status)
        new = repository.NewJob(index=0, budget=150_000, out_dir=str(tmp_path / "job"))
        [job] = repository.create_jobs(session, mission_id, [new])
        assert repository.claim_job(session, job.id, "worker") is not None
        repository.record_progress(session, job.id, 65_000, 0.88, 700.0)
        repository.record_evaluating(session, job.id, what)

    with example_submitted(tmp_path, page, train):
        page.locator("#training .detail").filter(has_text=what).wait_for()
        assert "ETA" not in page.inner_text("#training .detail")


@pytest.mark.timeout(120)
def test_api_key_field_sends_the_bearer_token(tmp_path: Path, page: Any) -> None:
    settings = quick_settings(tmp_path, api_keys=["s3cret"])
    with ThreadServer(settings, lambda _id: None) as server:
        page.goto(server.url + "/")
        banner = page.locator("#error")
        banner.filter(has_text="401").wait_for()

        page.fill("#api-key", "s3cret")
        page.click("#key-form button")
        page.wait_for_selector("#no-missions")
        assert banner.is_hidden()

        page.reload()
        page.wait_for_selector("#no-missions")
        assert page.input_value("#api-key") == "s3cret"


# ------------------------------------------------------------------ end to end, real server


def clean_environment(**extra: str) -> dict[str, str]:
    env = {
        k: v for k, v in os.environ.items() if not k.startswith("LTLNAV_") and k != "DATABASE_URL"
    }
    env.update(extra)
    return env


def server_command(port: int) -> list[str]:
    """``ltlnav serve``: migrations, the API and an embedded Celery worker (2 processes)."""
    ltlnav = str(Path(sys.executable).with_name("ltlnav"))
    return [ltlnav, "serve", "--host", "127.0.0.1", "--port", str(port), "--workers", "2"]


def stop(process: subprocess.Popen[bytes]) -> None:
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)


@pytest.fixture
def served(tmp_path: Path) -> Iterator[str]:
    """``ltlnav serve`` on the embedded defaults, data under ``tmp_path``, on a free port."""
    examples = tmp_path / "examples"
    write_example(examples, n_timesteps=300, eval_freq=100)
    port = free_port()
    log_path = tmp_path / "serve.log"
    env = clean_environment(
        LTLNAV_DATA_DIR=str(tmp_path / "data"),
        LTLNAV_EXAMPLES_DIR=str(examples),
        LTLNAV_HEARTBEAT_SECONDS="0.2",
    )
    url = f"http://127.0.0.1:{port}"
    with log_path.open("w") as log:
        process = subprocess.Popen(
            server_command(port),
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 60
        while True:
            assert process.poll() is None, f"ltlnav serve exited:\n{log_path.read_text()}"
            assert time.monotonic() < deadline, f"no /healthz after 60 s:\n{log_path.read_text()}"
            try:
                if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        yield url
    finally:
        stop(process)
        print(log_path.read_text()[-4000:])


def snapshot(page: Any) -> tuple[str, list[int]]:
    """The mission status badge and the progress bars' steps, as the page shows them."""
    status = page.locator("#mission-status .badge").inner_text(timeout=5_000)
    bars = page.locator("#training [role=progressbar]")
    steps = [int(bars.nth(i).get_attribute("aria-valuenow")) for i in range(bars.count())]
    return status, steps


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_submit_watch_progress_and_download_the_bundle(
    served: str, page: Any, tmp_path: Path
) -> None:
    from workers.bundle_reader import read_bundle

    page.goto(served + "/")
    page.select_option("#example", EXAMPLE)
    page.click("#submit")
    page.wait_for_url("**/#/missions/*")

    seen: list[tuple[str, list[int]]] = []
    deadline = time.monotonic() + 240
    while True:
        state = snapshot(page)
        seen.append(state)
        if state[0] in ("done", "failed", "cancelled"):
            break
        assert time.monotonic() < deadline, f"mission not finished in 240 s: {seen[-5:]}"
        time.sleep(0.2)
    status, steps = seen[-1]
    assert status == "done", page.locator("#mission-reason").all_inner_texts()
    assert len(steps) == 4 and all(s >= 300 for s in steps)
    training = [s for st, s in seen if st == "training" and s]
    assert training, f"no progress bars while training: {seen}"
    assert any(sum(s) > 0 for s in training), "progress never moved while training"

    page.locator("#evaluation table").first.wait_for()
    times = page.locator("#jobs .job-time")
    assert times.count() == 4
    assert "final evaluation" in (times.first.get_attribute("title") or "")
    page.locator("#curves .curve svg path.line").first.wait_for(state="attached")
    assert page.locator("#curves .curve").count() == 4
    assert page.locator("img.plan-img").first.evaluate("img => img.naturalWidth") > 0
    rollout = page.locator("#bundle-pictures img").first
    rollout.wait_for()
    page.wait_for_function(
        "img => img.complete && img.naturalWidth > 0", arg=rollout.element_handle()
    )

    with page.expect_download() as info:
        page.click("#download")
    target = tmp_path / "downloaded.zip"
    info.value.save_as(target)
    manifest, models = read_bundle(target)
    assert len(manifest.subtasks) == 4
    assert len(models) == 4
