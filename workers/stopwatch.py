"""Where a training job's wall time goes: seconds per part (periodic evaluations,
confirmations, checkpoints, ...), each part's own time only (``TrainResult.parts``)."""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

LEARNER = "learner and the rest"
"""The part that is not timed on its own: the learner's steps and what surrounds them."""


class Stopwatch:
    """Wall seconds per named part; a part timed inside another counts for itself only."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._inner: list[float] = []
        """For each part being timed, the seconds of the parts timed inside it so far."""

    @contextmanager
    def part(self, name: str) -> Iterator[None]:
        """Time the body as part ``name``."""
        start = time.perf_counter()
        self._inner.append(0.0)
        try:
            yield
        finally:
            elapsed = time.perf_counter() - start
            inner = self._inner.pop()
            self.seconds[name] = self.seconds.get(name, 0.0) + elapsed - inner
            if self._inner:
                self._inner[-1] += elapsed

    def split(self, total: float) -> dict[str, float]:
        """The parts of ``total`` seconds: the timed ones and, under ``LEARNER``, the rest."""
        timed = {name: round(seconds, 3) for name, seconds in sorted(self.seconds.items())}
        return {**timed, LEARNER: round(max(0.0, total - sum(self.seconds.values())), 3)}


def largest_first(parts: Mapping[str, float]) -> str:
    """``learner and the rest 625, periodic evaluations 246, ...``: parts in whole seconds."""
    return ", ".join(f"{name} {s:.0f}" for name, s in sorted(parts.items(), key=lambda p: -p[1]))


def added(first: Mapping[str, float], second: Mapping[str, float]) -> dict[str, float]:
    """The parts of two calls together."""
    return {k: round(first.get(k, 0.0) + second.get(k, 0.0), 3) for k in {*first, *second}}
