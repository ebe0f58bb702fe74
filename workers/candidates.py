"""The policies of a job's best periodic evaluations, kept on disk for the pick at its end
(``training.pick_candidates``, ``workers.policy_pick``).

A folder of ``policy_<steps>.zip`` files and ``index.json`` (``[[steps, success rate], ...]``,
best first). The index is rewritten atomically after each policy file is in place, so it
never names a file that is not there; files it does not name are removed.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from workers.atomic import save_with, write_json

INDEX = "index.json"


@dataclass(frozen=True)
class Candidate:
    """The policy at ``steps``, whose periodic evaluation made ``success_rate``."""

    steps: int
    success_rate: float
    path: Path


class CandidateStore:
    """The ``keep`` best periodic evaluations' policies in ``folder``: ranked by success rate,
    then by the earlier step (the first of equal rates stays, as with the kept best policy)."""

    def __init__(self, folder: Path, keep: int) -> None:
        self.folder, self.keep = folder, keep
        self.candidates: list[Candidate] = self._read()

    def ranked(self) -> list[Candidate]:
        """The candidates, best first."""
        return list(self.candidates)

    def wanted(self, steps: int, success_rate: float) -> bool:
        """Whether an evaluation at ``steps`` making ``success_rate`` would be kept."""
        if any(c.steps == steps for c in self.candidates):
            return False
        return len(self.candidates) < self.keep or _rank(success_rate, steps) < _rank(
            self.candidates[-1].success_rate, self.candidates[-1].steps
        )

    def add(self, steps: int, success_rate: float, save: Callable[[Path], None]) -> None:
        """Keep the policy ``save(path)`` writes, evaluated at ``success_rate`` after
        ``steps`` (if ``wanted``), dropping the one it pushes out."""
        if not self.wanted(steps, success_rate):
            return
        path = self.folder / f"policy_{steps}.zip"
        save_with(path, save)
        found = [*self.candidates, Candidate(steps, success_rate, path)]
        found.sort(key=lambda c: _rank(c.success_rate, c.steps))
        self._write(found[: self.keep])

    def restore(self, upto: int) -> None:
        """Drop the candidates of steps after ``upto`` (a resumed job redoes those steps)."""
        if any(c.steps > upto for c in self.candidates):
            self._write([c for c in self.candidates if c.steps <= upto])

    def _write(self, candidates: list[Candidate]) -> None:
        self.candidates = candidates
        write_json(self.folder / INDEX, [[c.steps, c.success_rate] for c in candidates])
        named = {c.path.name for c in candidates} | {INDEX}
        for stale in self.folder.glob("policy_*.zip"):
            if stale.name not in named:
                stale.unlink(missing_ok=True)

    def _read(self) -> list[Candidate]:
        try:
            stored = json.loads((self.folder / INDEX).read_text())
            found = [
                Candidate(int(s), float(r), self.folder / f"policy_{int(s)}.zip") for s, r in stored
            ]
        except (OSError, ValueError, TypeError):
            return []
        return [c for c in found if c.path.is_file()][: self.keep]


def _rank(success_rate: float, steps: int) -> tuple[float, int]:
    return -success_rate, steps
