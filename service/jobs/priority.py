"""A worker's place behind the API for the CPU.

Planning and training are batch work that uses every core; the API, the dashboard and
interactive use of the machine come first. A worker raises its niceness at start, which its
pool children inherit. On Linux with autogroup scheduling (``kernel.sched_autogroup_enabled``,
on in most distributions) the CPU is shared between sessions first and niceness counts only
inside a session: a worker in a session of its own, as ``ltlnav serve`` and the benchmarks
start it, then takes an equal share with the API whatever its niceness. Measured under the
500-mission load (``bench/service.py --load``): two workers at niceness 10 in their own
sessions took 109 % of the two cores while the API's threads waited in the run queue as long
as they ran. Such a worker lowers its session's group too.
"""

from __future__ import annotations

import os
from contextlib import suppress
from pathlib import Path

AUTOGROUP = Path("/proc/self/autogroup")
"""Linux: this process's autogroup and its niceness (``/autogroup-85 nice 0``); writable."""

MAX_NICE = 19


def lower_priority(increment: int) -> None:
    """Add ``increment`` to this process's niceness and, when it leads its own session, to
    that session's autogroup. No-op where ``os.nice`` is missing; a group that cannot be
    read or written (no autogroup support) is left as it is."""
    if not increment or not hasattr(os, "nice"):
        return
    os.nice(increment)
    if os.getsid(0) == os.getpid():  # a group shared with a shell would lower the shell too
        _lower_autogroup(increment)


def _lower_autogroup(increment: int) -> None:
    current = autogroup_nice()
    if current is not None:
        with suppress(OSError):
            AUTOGROUP.write_text(str(min(MAX_NICE, current + increment)))


def autogroup_nice() -> int | None:
    """This process's autogroup niceness; None without autogroup support."""
    try:
        return int(AUTOGROUP.read_text().split()[-1])
    except (OSError, ValueError, IndexError):
        return None
