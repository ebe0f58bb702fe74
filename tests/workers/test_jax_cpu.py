"""``training.backend: sbx`` bounds XLA's CPU threads by ``torch_threads`` and leaves every thread
free to run on every CPU of the process; each case runs in a fresh process, since XLA's backend
starts once per process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity"), reason="CPU affinity is Linux's: XLA sizes its own pool"
)

PROBE = """
import json, os, sys
threads = int(sys.argv[1])
if threads:
    from workers.agents import algorithm_class
    from workers.training_spec import TrainingSpec
    algorithm_class(TrainingSpec(backend="sbx", torch_threads=threads))
import jax, jax.numpy as jnp
x = jnp.ones((256, 256))
jax.jit(lambda a: a @ a)(x).block_until_ready()
tasks = [int(t) for t in os.listdir("/proc/self/task")]
names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in tasks]
print(json.dumps({
    "pool": names.count("tf_XLAEigen"),
    "cpus": sorted(os.sched_getaffinity(0)),
    "affinities": sorted({tuple(sorted(os.sched_getaffinity(t))) for t in tasks}),
}))
"""


def _fresh_process(script: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``script`` run by this Python in a process of its own (its output captured)."""
    return subprocess.run(
        [sys.executable, "-c", script, *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )


def _probe(torch_threads: int) -> dict[str, list[int] | int]:
    """The XLA pool's size and the threads' CPUs in a process that built an SBX learner with
    ``torch_threads`` (0: JAX started directly, XLA's own choice)."""
    done = _fresh_process(PROBE, str(torch_threads))
    result: dict[str, list[int] | int] = json.loads(done.stdout.splitlines()[-1])
    return result


def test_xla_alone_takes_more_than_one_thread_where_there_are_cpus_for_them() -> None:
    cpus = len(os.sched_getaffinity(0))
    if cpus < 2:
        pytest.skip("one CPU: XLA's own pool has one thread too")
    probe = _probe(0)
    assert isinstance(probe["pool"], int) and probe["pool"] > 1


@pytest.mark.parametrize("torch_threads", [1, 2])
def test_the_sbx_backend_gives_xla_torch_threads_threads_free_on_every_cpu(
    torch_threads: int,
) -> None:
    cpus = sorted(os.sched_getaffinity(0))
    if torch_threads == 1 and len(cpus) < 2:
        pytest.skip("one CPU: XLA's own pool would have one thread too")
    probe = _probe(torch_threads)
    assert probe["pool"] == min(torch_threads, len(cpus))
    assert probe["cpus"] == cpus
    assert probe["affinities"] == [cpus]


WARNING_PROBE = """
from workers.jax_cpu import start_jax_cpu
print(start_jax_cpu(1), flush=True)
print(start_jax_cpu(1), flush=True)
print(start_jax_cpu(2), flush=True)
"""


def test_a_later_job_with_other_threads_is_told_the_pool_it_gets() -> None:
    done = _fresh_process(WARNING_PROBE)
    assert done.stdout.split() == ["1", "1", "1"]
    warnings = [line for line in done.stderr.splitlines() if "thread pool" in line]
    assert warnings == [
        "XLA's thread pool stays at 1 thread(s) (its backend started earlier in this "
        "process): torch_threads=2 bounds torch only"
    ]
