"""The bundled example missions (``Settings.examples_dir``): listed and submitted by name."""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.errors import LtlnavError
from workers.documents import read_document
from workers.mission import MissionSpec, parse_mission

log = logging.getLogger(__name__)

SUFFIXES = (".yaml", ".yml", ".json")


@dataclass(frozen=True)
class Example:
    """A valid example mission: its name (file stem), raw document and validated spec."""

    name: str
    document: dict[str, Any]
    spec: MissionSpec


class ExampleCatalogue:
    """The valid missions of a folder, re-read when a file changes (invalid ones are logged
    and left out)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._cache: dict[Path, tuple[int, Example | None]] = {}
        self._lock = threading.Lock()

    def _files(self) -> list[Path]:
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if p.suffix in SUFFIXES and p.is_file())

    def _load(self, path: Path) -> Example | None:
        try:
            document = read_document(path)
            spec = parse_mission(document)
        except (ValueError, LtlnavError) as error:
            log.warning("example %s is not a valid mission, left out: %s", path, error)
            return None
        return Example(name=path.stem, document=document, spec=spec)

    def all(self) -> list[Example]:
        """Every valid example, by name."""
        found = []
        with self._lock:
            for path in self._files():
                stamp = path.stat().st_mtime_ns
                cached = self._cache.get(path)
                if cached is None or cached[0] != stamp:
                    cached = (stamp, self._load(path))
                    self._cache[path] = cached
                if cached[1] is not None:
                    found.append(cached[1])
        return found

    def get(self, name: str) -> Example | None:
        """The example called ``name``, if any."""
        return next((e for e in self.all() if e.name == name), None)
