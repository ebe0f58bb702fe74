"""JAX on the CPU with as many XLA threads as a job has torch threads (``training.backend: sbx``).

XLA sizes the thread pool of its CPU backend by the CPUs the process may run on when the backend
starts, and in this JAX (0.10) no flag changes that (``XLA_FLAGS``' ``xla_cpu_multi_thread_eigen``
and ``intra_op_parallelism_threads`` left a 512 x 512 matmul at 1.8 CPU seconds per second on two
cores). So the backend is started with the calling thread restricted to ``threads`` of its CPUs;
the threads it creates inherit that restriction, and both they and the caller get their CPUs back
at once: the pool keeps its size and its threads run on any CPU. The backend starts once per
process, so the first job of a worker process decides its pool.
"""

from __future__ import annotations

import contextlib
import logging
import os

log = logging.getLogger(__name__)

_started: tuple[int, int] | None = None
"""``(threads asked for, the pool's size)`` when this module started the backend (None: it
did not)."""


def start_jax_cpu(threads: int) -> int | None:
    """Start JAX's CPU backend with an XLA pool of ``threads`` threads (at most the CPUs this
    process may use), unless it has started already; returns the pool's size when this module
    started it (None when something else did, so its size is unknown)."""
    global _started
    os.environ.setdefault("JAX_PLATFORMS", "cpu")  # no probing for accelerators
    import jax
    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        if _started is None or _started[0] != threads:
            pool = "the size XLA chose" if _started is None else f"{_started[1]} thread(s)"
            log.warning(
                "XLA's thread pool stays at %s (its backend started earlier in this process): "
                "torch_threads=%d bounds torch only",
                pool,
                threads,
            )
        return None if _started is None else _started[1]
    if not hasattr(os, "sched_setaffinity"):  # not Linux: XLA sizes its pool by itself
        jax.devices()
        return None
    cpus = os.sched_getaffinity(0)
    size = min(threads, len(cpus))
    existing = _threads()
    os.sched_setaffinity(0, set(sorted(cpus)[:size]))
    try:
        jax.devices()
    finally:
        for thread in _threads() - existing:
            with contextlib.suppress(ProcessLookupError):  # a thread that has ended since
                os.sched_setaffinity(thread, cpus)
        os.sched_setaffinity(0, cpus)
    _started = (threads, size)
    return size


def _threads() -> set[int]:
    """The ids of this process's threads."""
    return {int(tid) for tid in os.listdir("/proc/self/task")}
