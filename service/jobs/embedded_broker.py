"""kombu's SQLAlchemy transport (the embedded broker), made to recover from a failed statement.

kombu's channel keeps one ORM session for its life and commits it after every read of the
queue, but it rolls back only some failures. When SQLite refuses a COMMIT (the file locked by
another process for longer than the busy timeout), SQLAlchemy leaves that session "prepared",
and every later statement of the channel raises ``InvalidRequestError``: the worker's consumer
never reads the queue again. This channel rolls the session back after any failure, so the
failed read is retried with the message still visible, as kombu does for a failed publish.
"""

from __future__ import annotations

from queue import Empty
from typing import Any

from kombu.transport import sqlalchemy as kombu_sqla


class RecoveringChannel(kombu_sqla.Channel):
    """A kombu SQLAlchemy channel whose session survives a failed statement or commit."""

    def _rolled_back_on_failure(self, operation: str, *args: Any, **kwargs: Any) -> Any:
        try:
            return getattr(super(), operation)(*args, **kwargs)
        except Empty:
            raise
        except Exception:
            self.session.rollback()
            raise

    def _get(self, *args: Any, **kwargs: Any) -> Any:
        return self._rolled_back_on_failure("_get", *args, **kwargs)

    def _put(self, *args: Any, **kwargs: Any) -> Any:
        return self._rolled_back_on_failure("_put", *args, **kwargs)

    def _new_queue(self, *args: Any, **kwargs: Any) -> Any:
        return self._rolled_back_on_failure("_new_queue", *args, **kwargs)

    def _size(self, *args: Any, **kwargs: Any) -> Any:
        return self._rolled_back_on_failure("_size", *args, **kwargs)

    def _purge(self, *args: Any, **kwargs: Any) -> Any:
        return self._rolled_back_on_failure("_purge", *args, **kwargs)


def install() -> None:
    """Make every ``sqla+`` connection of this process use ``RecoveringChannel``."""
    kombu_sqla.Transport.Channel = RecoveringChannel
