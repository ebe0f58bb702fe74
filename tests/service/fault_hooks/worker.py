"""A Celery worker with injected faults: ``python -m tests.service.fault_hooks.worker``.

It installs what its ``FAULT_*`` environment variables ask for (read here only, never by the
service), then runs ``service.jobs.celery_app.run_worker`` as ``ltlnav worker`` does; the
prefork children inherit the patches. Without ``FAULT_*`` variables it is a plain worker.

- ``FAULT_ENOSPC_ONCE=<marker>``: the first checkpoint model file saved at or after
  ``FAULT_ENOSPC_AFTER`` steps (default 1) by any process fails with ``OSError(ENOSPC)``, as a
  full disk would; ``<marker>`` (created exclusively) makes it once across processes and
  records the failed step.
- ``FAULT_POISON=<mission name>``: planning a mission of that name ends its process with
  ``os._exit(1)`` (a crash of the planner, every time).
- ``FAULT_STALL_PLAN`` / ``FAULT_STALL_ASSEMBLE=<seconds>``: planning / assembly sleeps that
  long after its claim (inside its heartbeat), so that a test can kill it mid-step.
- ``FAULT_CLOCK_AHEAD=<seconds>``: this process's clocks (``time.time`` and the host clock
  ``service.repository.clock`` reads) run that far ahead.
"""

from __future__ import annotations

import errno
import os
import sys
import time
from collections.abc import Callable, Mapping
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any


def _enospc_once(marker: Path, after: int) -> None:
    import workers.checkpoints as checkpoints

    save_with = checkpoints.save_with

    def failing_save(path: Path, save: Callable[[Path], None], durable: bool = False) -> None:
        steps = checkpoints.checkpoint_steps(path)
        if steps is not None and steps >= after:
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                pass
            else:
                os.write(fd, f"{steps} {time.time()}\n".encode())
                os.close(fd)
                raise OSError(errno.ENOSPC, "No space left on device (injected)", str(path))
        save_with(path, save, durable)

    checkpoints.save_with = failing_save


def _wrap_open_run(module: Any, before: Callable[[Mapping[str, Any]], None]) -> None:
    original = module.open_run

    def open_run(settings: Any, mission_id: str, document: Mapping[str, Any]) -> Any:
        before(document)
        return original(settings, mission_id, document)

    module.open_run = open_run


def _clock_ahead(seconds: float) -> None:
    import service.repository.clock as clock

    real_time = time.time
    utcnow = clock.utcnow

    def skewed_time() -> float:
        return real_time() + seconds

    def skewed_utcnow() -> datetime:
        return utcnow() + timedelta(seconds=seconds)

    time.time = skewed_time
    clock.utcnow = skewed_utcnow


def _sleeper(seconds: float) -> Callable[[Mapping[str, Any]], None]:
    def sleep(_document: Mapping[str, Any]) -> None:
        time.sleep(seconds)

    return sleep


def install(env: Mapping[str, str]) -> list[str]:
    """Install the faults ``env`` asks for; their names."""
    import service.jobs.assembly as assembly
    import service.jobs.planning as planning

    installed: list[str] = []
    marker = env.get("FAULT_ENOSPC_ONCE")
    if marker:
        _enospc_once(Path(marker), int(env.get("FAULT_ENOSPC_AFTER", "1")))
        installed.append("enospc")
    poison = env.get("FAULT_POISON")
    if poison:

        def crash(document: Mapping[str, Any]) -> None:
            if document.get("name") == poison:
                os._exit(1)

        _wrap_open_run(planning, crash)
        installed.append("poison")
    for module, key in ((planning, "FAULT_STALL_PLAN"), (assembly, "FAULT_STALL_ASSEMBLE")):
        stall = float(env.get(key, "0"))
        if stall > 0:
            _wrap_open_run(module, _sleeper(stall))
            installed.append(key.lower())
    ahead = float(env.get("FAULT_CLOCK_AHEAD", "0"))
    if ahead:
        _clock_ahead(ahead)
        installed.append("clock")
    return installed


def main() -> None:
    """Install the faults, then run a worker (``sys.argv[1]``: concurrency, default 2)."""
    from service.jobs.celery_app import run_worker

    faults = install(os.environ)
    print(f"fault worker {os.getpid()}: {faults or 'no faults'}", flush=True)
    run_worker(concurrency=int(sys.argv[1]) if len(sys.argv) > 1 else 2)


if __name__ == "__main__":
    main()
