"""Hand-over repair rounds as job rows: jobs.repair_round and jobs.spec, missions.repairs.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-03 00:20:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")


def upgrade() -> None:
    """A job's round (0 for every existing job) and stored spec; the mission's repair rounds;
    one job per (mission, sub-task, round)."""
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(
            sa.Column("repair_round", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("spec", JSON, nullable=True))
        batch.drop_constraint("uq_jobs_mission_id_index", type_="unique")
        batch.create_unique_constraint(
            "uq_jobs_mission_id_index_round", ["mission_id", "index", "repair_round"]
        )
    with op.batch_alter_table("missions") as batch:
        batch.add_column(sa.Column("repairs", JSON, nullable=True))


def downgrade() -> None:
    """Back to one job per sub-task (repair rows are dropped)."""
    op.execute("DELETE FROM jobs WHERE repair_round > 0")
    with op.batch_alter_table("missions") as batch:
        batch.drop_column("repairs")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_constraint("uq_jobs_mission_id_index_round", type_="unique")
        batch.create_unique_constraint("uq_jobs_mission_id_index", ["mission_id", "index"])
        batch.drop_column("spec")
        batch.drop_column("repair_round")
