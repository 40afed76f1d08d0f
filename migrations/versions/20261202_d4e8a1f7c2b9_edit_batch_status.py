"""edit batches get a status, so a revision whose job died frees its number

``edit_batches.status`` (pending | ready | failed | discarded), ``error`` and ``failed_at``;
the unique ``(run_id, revision)`` constraint becomes a unique index over live batches
(pending, ready), so after a failed batch the run's head goes back and the next batch can
claim the same number. Existing batches are ``ready`` when their revision exists, else
``pending`` (a job that already died is failed by the worker's next clean-up).

Revision ID: d4e8a1f7c2b9
Revises: c3a9f1d2e4b5
Create Date: 2026-12-02 00:30:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "d4e8a1f7c2b9"
down_revision = "c3a9f1d2e4b5"
branch_labels = None
depends_on = None

LIVE = "status IN ('pending', 'ready')"


def upgrade() -> None:
    with op.batch_alter_table("edit_batches", schema=None) as batch_op:
        batch_op.add_column(sa.Column("status", sa.String(length=16), nullable=False, server_default="pending"))
        batch_op.add_column(sa.Column("error", sa.Text(), nullable=True))
        batch_op.add_column(sa.Column("failed_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.drop_constraint("uq_edit_batches_run_id_revision", type_="unique")
    op.execute(
        "UPDATE edit_batches SET status = 'ready' WHERE EXISTS (SELECT 1 FROM revisions r "
        "WHERE r.run_id = edit_batches.run_id AND r.number = edit_batches.revision)"
    )
    with op.batch_alter_table("edit_batches", schema=None) as batch_op:
        batch_op.alter_column("status", server_default=None)
    op.create_index("uq_edit_batches_live_revision", "edit_batches", ["run_id", "revision"], unique=True,
                    sqlite_where=sa.text(LIVE), postgresql_where=sa.text(LIVE))


def downgrade() -> None:
    op.drop_index("uq_edit_batches_live_revision", table_name="edit_batches")
    # failed and discarded batches held no revision: they go, with their edits
    op.execute("DELETE FROM edits WHERE batch_id IN (SELECT id FROM edit_batches WHERE status NOT IN ('pending', 'ready'))")
    op.execute("DELETE FROM edit_batches WHERE status NOT IN ('pending', 'ready')")
    with op.batch_alter_table("edit_batches", schema=None) as batch_op:
        batch_op.create_unique_constraint("uq_edit_batches_run_id_revision", ["run_id", "revision"])
        batch_op.drop_column("failed_at")
        batch_op.drop_column("error")
        batch_op.drop_column("status")
