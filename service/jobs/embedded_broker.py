"""kombu's SQLAlchemy transport (the embedded broker), made to recover from a failed statement.

kombu's channel keeps one ORM session for its life and commits it after every read of the
queue, but it rolls back only some failures. When SQLite refuses a COMMIT (the file locked by
another process for longer than the busy timeout), SQLAlchemy leaves that session "prepared",
and every later statement of the channel raises ``InvalidRequestError``: the worker's consumer
never reads the queue again. This channel rolls the session back after any failure, so the
failed read is retried with the message still visible, as kombu does for a failed publish; a
session that cannot even roll back is replaced by a fresh one.
"""

from __future__ import annotations

import contextlib
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
            if self._rolled_back() or operation != "_get":
                raise
            raise Empty() from None  # the next poll reads again, on a fresh session

    def _rolled_back(self) -> bool:
        """Roll the session back; a session that cannot even do that is dropped (its
        uncommitted work with it) for a fresh one, and the answer is False.

        Seen once under load: a session left "prepared" with SQLAlchemy's bookkeeping still
        showing its commit in progress (a pool child had just died), so that ``rollback()``
        raised ``IllegalStateChangeError`` and the worker's consumer stopped for good."""
        try:
            self.session.rollback()
            return True
        except Exception:
            session, self._session = self._session, None
            if session is not None:
                _close_connections(session)
            return False

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


def _close_connections(session: Any) -> None:
    """Close the DBAPI connections of ``session`` for good, not back into the pool: they may
    hold SQLite's write lock in the transaction that could not end. The ORM's own ``close`` and
    ``invalidate`` refuse a session in that state, so its Core connections are reached through
    the transaction's (private) table of them."""
    transaction = session.get_transaction()
    found = getattr(transaction, "_connections", {}) if transaction is not None else {}
    for connection, *_ in list(found.values()):
        with contextlib.suppress(Exception):
            connection.invalidate()


def install() -> None:
    """Make every ``sqla+`` connection of this process use ``RecoveringChannel``."""
    kombu_sqla.Transport.Channel = RecoveringChannel
