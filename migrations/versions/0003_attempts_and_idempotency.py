"""Attempt counts of planning and assembly, submission idempotency keys, job backoff.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-03 00:55:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """missions.plan_attempts, assembly_attempts (0 for existing rows), idempotency_key with
    its (owner, key) index; jobs.not_before."""
    with op.batch_alter_table("missions") as batch:
        batch.add_column(
            sa.Column("plan_attempts", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(
            sa.Column("assembly_attempts", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("idempotency_key", sa.String(length=200), nullable=True))
        batch.create_index("ix_missions_owner_idempotency_key", ["owner", "idempotency_key"])
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("not_before", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    """Drop them."""
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("not_before")
    with op.batch_alter_table("missions") as batch:
        batch.drop_index("ix_missions_owner_idempotency_key")
        batch.drop_column("idempotency_key")
        batch.drop_column("assembly_attempts")
        batch.drop_column("plan_attempts")
