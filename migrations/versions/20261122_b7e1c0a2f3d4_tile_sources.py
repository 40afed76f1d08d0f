"""tile sources

Revision ID: b7e1c0a2f3d4
Revises: 26740de95728
Create Date: 2026-11-22 03:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "b7e1c0a2f3d4"
down_revision = "26740de95728"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "tile_sources",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("title", sa.String(length=200), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("attribution", sa.String(length=1000), nullable=False),
        sa.Column("min_zoom", sa.Integer(), nullable=False),
        sa.Column("max_zoom", sa.Integer(), nullable=False),
        sa.Column("format", sa.String(length=8), nullable=False),
        sa.Column("path", sa.String(length=1000), nullable=True),
        sa.Column("url", sa.String(length=2000), nullable=True),
        sa.Column("encoding", sa.String(length=16), nullable=True),
        sa.Column("tile_size", sa.Integer(), nullable=False),
        sa.Column("bounds", sa.JSON(), nullable=True),
        sa.Column("vector_layers", sa.JSON(), nullable=False),
        sa.Column("style_schema", sa.String(length=64), nullable=False),
        sa.Column("created_by_id", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["created_by_id"], ["users.id"], name=op.f("fk_tile_sources_created_by_id_users"), ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_tile_sources")),
        sa.UniqueConstraint("name", name=op.f("uq_tile_sources_name")),
    )


def downgrade() -> None:
    op.drop_table("tile_sources")
