"""The embedded broker's channel recovers from a COMMIT that SQLite refuses."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from queue import Empty
from typing import Any

import pytest
from kombu import Connection
from kombu.transport import sqlalchemy as kombu_sqla
from sqlalchemy.exc import InvalidRequestError, OperationalError
from sqlalchemy.orm.state_changes import _StateChangeStates

from service.jobs import celery_app  # noqa: F401  (installs the embedded broker's channel)
from service.jobs.embedded_broker import RecoveringChannel


@pytest.fixture
def channel(tmp_path: Path) -> Iterator[Any]:
    with Connection(f"sqla+sqlite:///{tmp_path / 'broker.db'}") as connection:
        yield connection.default_channel


def refuse_next_commit(channel: Any) -> None:
    dialect = channel.session.get_bind().dialect
    do_commit = dialect.do_commit

    def locked(dbapi_connection: Any) -> None:
        dialect.do_commit = do_commit
        raise sqlite3.OperationalError("database is locked")

    dialect.do_commit = locked


def test_every_sqla_connection_uses_the_recovering_channel(channel: Any) -> None:
    assert isinstance(channel, RecoveringChannel)


def test_a_refused_commit_leaves_the_message_for_the_next_read(channel: Any) -> None:
    channel._put("jobs", {"task": "plan"})
    refuse_next_commit(channel)
    with pytest.raises(OperationalError, match="database is locked"):
        channel._get("jobs")
    assert channel._get("jobs") == {"task": "plan"}
    assert channel._size("jobs") == 0


def commit_in_progress(session: Any) -> None:
    """Make the next commit of ``session`` leave it as if that commit were still running."""
    commit = session.commit

    def interrupted() -> None:
        transaction = session._transaction
        try:
            commit()
        finally:
            transaction._current_fn = type(transaction).commit
            transaction._next_state = _StateChangeStates.CHANGE_IN_PROGRESS

    session.commit = interrupted


def test_a_session_that_cannot_roll_back_is_replaced_and_the_message_read_again(
    channel: Any,
) -> None:
    """The state a worker's consumer died in under load: a refused COMMIT left the session
    "prepared" while SQLAlchemy's bookkeeping still showed the commit in progress."""
    channel._put("jobs", {"task": "plan"})
    stuck = channel.session
    refuse_next_commit(channel)
    commit_in_progress(stuck)
    with pytest.raises(Empty):
        channel._get("jobs")
    assert channel.session is not stuck
    assert channel._get("jobs") == {"task": "plan"}
    assert channel._size("jobs") == 0


def test_kombus_own_channel_is_stuck_after_a_refused_commit(tmp_path: Path) -> None:
    """The failure the recovering channel exists for: if kombu fixes it, drop the subclass."""
    with Connection(f"sqla+sqlite:///{tmp_path / 'broker.db'}") as connection:
        channel = kombu_sqla.Channel(connection.transport)
        channel._put("jobs", {"task": "plan"})
        refuse_next_commit(channel)
        with pytest.raises(OperationalError):
            channel._get("jobs")
        with pytest.raises(InvalidRequestError, match="prepared"):
            channel._get("jobs")
        channel.close()


def test_a_refused_publish_stores_nothing_and_the_channel_goes_on(channel: Any) -> None:
    channel._new_queue("jobs")
    refuse_next_commit(channel)
    with pytest.raises(OperationalError):
        channel._put("jobs", {"task": "lost"})
    channel._put("jobs", {"task": "kept"})
    assert channel._size("jobs") == 1
    assert channel._get("jobs") == {"task": "kept"}
