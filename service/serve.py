"""``ltlnav serve``: the API (uvicorn) in this process, or in ``api_processes`` children of it,
and one embedded Celery worker in a child process, all stopped cleanly on Ctrl-C or SIGTERM.
The open API (no keys) binds loopback addresses only."""

from __future__ import annotations

import contextlib
import ipaddress
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from types import FrameType

import uvicorn

from service.db import upgrade
from service.settings import Settings

WORKER_GRACE_SECONDS = 20.0
"""How long a stopping worker may take for its warm shutdown (an idle one takes ~10 s here)
before it is shut down cold; jobs cut short resume from their checkpoints later."""

Say = Callable[[str], None]


class OpenExposureError(ValueError):
    """The open API (no keys) asked to listen beyond this machine."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` is reachable from this machine only: ``localhost`` or a loopback
    address (127.0.0.0/8, ::1). The wildcards (0.0.0.0, ::) and any other name are not."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def refuse_open_exposure(settings: Settings, host: str) -> None:
    """Raise ``OpenExposureError`` when the API is open (no ``LTLNAV_API_KEYS``) and ``host``
    is not a loopback address: an open API on a network lets anyone there, and any web page a
    user of it visits, submit and read missions."""
    if settings.api_keys or is_loopback(host):
        return
    raise OpenExposureError(
        f"refusing to serve the open API on {host!r}: with no API keys it must bind a "
        "loopback address (127.0.0.1, the default). Set LTLNAV_API_KEYS (comma-separated "
        "bearer tokens) to listen on other addresses, or use --host 127.0.0.1"
    )


def display_host(host: str) -> str:
    """A host a browser can open for ``host`` (the wildcard addresses become localhost)."""
    return "127.0.0.1" if host in ("0.0.0.0", "::", "") else host


def start_worker(concurrency: int | None) -> subprocess.Popen[bytes]:
    """``ltlnav worker`` as a child in its own session (a terminal's Ctrl-C reaches only us;
    we stop it in order)."""
    command = [sys.executable, "-m", "service.cli", "worker"]
    if concurrency is not None:
        command += ["--concurrency", str(concurrency)]
    return subprocess.Popen(command, start_new_session=True)


def stop_worker(worker: subprocess.Popen[bytes], say: Say) -> int | None:
    """Warm shutdown (SIGTERM), then cold (SIGQUIT), then SIGKILL of its process group."""
    if worker.poll() is not None:
        return worker.returncode
    say(f"stopping the worker (up to {WORKER_GRACE_SECONDS:g} s for running tasks)")
    for sig, wait in ((signal.SIGTERM, WORKER_GRACE_SECONDS), (signal.SIGQUIT, 5.0)):
        worker.send_signal(sig)
        try:
            return worker.wait(wait)
        except subprocess.TimeoutExpired:
            continue
    with contextlib.suppress(ProcessLookupError):
        os.killpg(worker.pid, signal.SIGKILL)
    return worker.wait()


def _watch(worker: subprocess.Popen[bytes], stopping: threading.Event, say: Say) -> None:
    code = worker.wait()
    if not stopping.is_set():
        say(
            f"warning: the embedded worker exited (code {code}); missions wait in the queue "
            "until a worker runs (`ltlnav worker`)"
        )


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def run_api(settings: Settings, host: str, port: int) -> None:
    """The API on ``host:port`` until a signal: in this process, or in
    ``settings.api_processes`` uvicorn workers, which build it from the environment's
    settings (``settings`` must be those)."""
    from service.api.app import create_app

    if settings.api_processes == 1:
        app = create_app(settings)
        uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="info")).run()
        return
    uvicorn.run(
        "service.api.app:create_app",
        factory=True,
        host=host,
        port=port,
        workers=settings.api_processes,
        log_level="info",
    )


def serve(
    settings: Settings,
    host: str,
    port: int,
    worker: bool,
    concurrency: int | None,
    say: Say,
) -> None:
    """Migrate, start the worker (unless ``worker`` is False) and serve the API until a
    signal; then stop both."""
    refuse_open_exposure(settings, host)
    settings.make_dirs()
    upgrade(settings.database_url)
    base = f"http://{display_host(host)}:{port}"
    if not settings.api_keys:
        say("the API is open: no API keys are configured (set LTLNAV_API_KEYS to require them)")
    child = start_worker(concurrency) if worker else None
    stopping = threading.Event()
    if child is not None:
        say(f"worker started (pid {child.pid}, concurrency {concurrency or settings.concurrency})")
        threading.Thread(target=_watch, args=(child, stopping, say), daemon=True).start()
    if settings.api_processes > 1:
        say(f"API in {settings.api_processes} processes")
    say(f"dashboard: {base}/   API docs: {base}/docs   data: {settings.data_dir}")
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        run_api(settings, host, port)
    except KeyboardInterrupt:
        pass
    finally:
        stopping.set()
        signal.signal(signal.SIGTERM, previous)
        if child is not None:
            code = stop_worker(child, say)
            say(f"worker stopped (exit code {code})")
    say("stopped")
