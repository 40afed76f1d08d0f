"""floor plans (map matching) and edit kind "suggestion"

Adds the ``floor_plans`` table and widens ``edits.kind`` from 8 to 16 characters so a
move accepted from a map-matching suggestion can be stored as kind ``suggestion``.

Revision ID: c3a9f1d2e4b5
Revises: b8f72baccca7
Create Date: 2026-11-22 03:45:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "c3a9f1d2e4b5"
down_revision = "b8f72baccca7"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "floor_plans",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("cell_m", sa.Float(), nullable=False),
        sa.Column("width_m", sa.Float(), nullable=False),
        sa.Column("height_m", sa.Float(), nullable=False),
        sa.Column("georef", sa.JSON(), nullable=True),
        sa.Column("has_image", sa.Boolean(), nullable=False),
        sa.Column("folder", sa.String(length=200), nullable=False),
        sa.Column("n_vertices", sa.Integer(), nullable=True),
        sa.Column("model_bytes", sa.Integer(), nullable=True),
        sa.Column("build_s", sa.Float(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("job_id", sa.Integer(), nullable=True),
        sa.Column("created_by_id", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("extra", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["created_by_id"], ["users.id"], name=op.f("fk_floor_plans_created_by_id_users"), ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_floor_plans")),
    )
    op.create_index(op.f("ix_floor_plans_status"), "floor_plans", ["status"], unique=False)
    with op.batch_alter_table("edits") as batch:
        batch.alter_column("kind", existing_type=sa.String(length=8), type_=sa.String(length=16), existing_nullable=False)


def downgrade() -> None:
    # Suggestion moves become plain moves: the old column cannot hold the longer name.
    op.execute("UPDATE edits SET kind = 'move' WHERE kind = 'suggestion'")
    with op.batch_alter_table("edits") as batch:
        batch.alter_column("kind", existing_type=sa.String(length=16), type_=sa.String(length=8), existing_nullable=False)
    op.drop_index(op.f("ix_floor_plans_status"), table_name="floor_plans")
    op.drop_table("floor_plans")
