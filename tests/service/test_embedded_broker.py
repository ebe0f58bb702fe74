"""The embedded broker's channel recovers from a COMMIT that SQLite refuses."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from kombu import Connection
from kombu.transport import sqlalchemy as kombu_sqla
from sqlalchemy.exc import InvalidRequestError, OperationalError

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
