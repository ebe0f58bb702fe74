"""The error of an env that cannot be built as asked."""

from __future__ import annotations

from planner.errors import FieldError


class EnvConfigError(FieldError, ValueError):
    """An env that cannot be built as asked: bad option, unknown reward mode, missing plan, a
    start of the wrong dimension... ``field`` names the culprit (``reward``, ``options.rays``)."""
