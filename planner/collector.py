"""Pausing Python's cyclic garbage collector while the planner builds large object graphs.

Reference counting frees the planner's objects as usual; what the pause saves are the full
collections that the collector triggers as the live objects grow. Each of those walks every
live object, and a large automaton brings hundreds of thousands of them (the 1024 states of
a ten-goal any-order visit: 59,049 transitions with their cubes), so they were repeated
while the automaton was built and again as the product trees grew. The collector runs
again, with everything it would have found, once the outermost pause ends.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def collection_paused() -> Iterator[None]:
    """No cyclic garbage collection inside (nested pauses are fine; usable as a decorator)."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
