"""Files written whole or not at all: to a temporary name in the same folder, then renamed.

A kill, a full disk or a power cut mid-write leaves the old file (or none) and a stray
temporary, never a truncated file that every retry would read first. ``durable`` also flushes
the data and the folder entry to disk before returning, for results a caller reports as done.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

TEMP_SUFFIX = ".partial"
"""Ending of a file being written (``<name>.<pid>.partial``)."""


@contextlib.contextmanager
def replacing(path: Path, durable: bool = False) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to; renamed over ``path`` when the
    block ends without an error, removed otherwise."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temp = path.with_name(f"{path.name}.{os.getpid()}{TEMP_SUFFIX}")
    try:
        yield temp
        if durable:
            _fsync(temp)
        os.replace(temp, path)
        if durable:
            _fsync_dir(path.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):
            temp.unlink()


def write_text(path: Path, text: str, durable: bool = False) -> None:
    """Replace ``path`` with ``text`` atomically."""
    with replacing(path, durable) as temp:
        temp.write_text(text)


def write_json(path: Path, document: Any, durable: bool = False, indent: int | None = 1) -> None:
    """Replace ``path`` with ``document`` as JSON atomically."""
    write_text(path, json.dumps(document, indent=indent), durable)


def save_with(path: Path, save: Callable[[Path], None], durable: bool = False) -> None:
    """Replace ``path`` with what ``save(temp_path)`` writes (an SB3 ``model.save``,
    ``np.savez``...) atomically. ``temp_path`` keeps ``path``'s suffix, since savers append
    their own when it is missing."""
    with replacing(path, durable) as temp:
        named = temp.with_name(temp.name + path.suffix)
        try:
            save(named)
            os.replace(named, temp)
        finally:
            with contextlib.suppress(FileNotFoundError):
                named.unlink()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # not every filesystem lets a folder be opened
        _fsync(folder)
