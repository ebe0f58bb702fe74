"""The service benchmarks' process harness (``bench/service.py``): a bench stopped with SIGTERM
stops the servers and workers it started, as Ctrl-C does, instead of leaving them running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

BENCH = """
import sys, time
from pathlib import Path
sys.path.insert(0, {root!r})
from bench.service import process, stop_on_sigterm

stop_on_sigterm()
with process(["sleep", "600"], {{}}, Path({log!r})) as child:
    print(child.pid, flush=True)
    time.sleep(600)
"""


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.timeout(60)
def test_sigterm_stops_the_processes_a_bench_started(tmp_path: Path) -> None:
    script = BENCH.format(root=str(ROOT), log=str(tmp_path / "child.log"))
    bench = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert bench.stdout is not None
    child = int(bench.stdout.readline())
    assert alive(child)

    bench.send_signal(signal.SIGTERM)
    _, stderr = bench.communicate(timeout=40)

    assert bench.returncode != 0
    assert "KeyboardInterrupt" in stderr
    deadline = time.monotonic() + 10
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(child), "the bench left the process it started running"
