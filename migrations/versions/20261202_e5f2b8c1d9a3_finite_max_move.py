"""max_move_m is always finite: stored rules with 0 ("unlimited") or beyond 10 km take 10 km

Settings now take 1 m to 10 km (``core.rules.MAX_MOVE_LIMIT_M``), and the rule check no
longer reads 0 as "no limit" (it would refuse every move). Runs' and tasks' stored rules
are brought into that range; 10 km keeps their moves as free as the setting allows.

Revision ID: e5f2b8c1d9a3
Revises: d4e8a1f7c2b9
Create Date: 2026-12-02 05:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "e5f2b8c1d9a3"
down_revision = "d4e8a1f7c2b9"
branch_labels = None
depends_on = None

LIMIT_M = 10_000.0


def _bounded(table: str) -> None:
    bind = op.get_bind()
    t = sa.table(table, sa.column("id", sa.Integer), sa.column("rules", sa.JSON))
    for row_id, rules in bind.execute(sa.select(t.c.id, t.c.rules).where(t.c.rules.is_not(None))).fetchall():
        if not isinstance(rules, dict) or "max_move_m" not in rules:
            continue
        value = float(rules["max_move_m"])
        if 1.0 <= value <= LIMIT_M:
            continue
        fixed = {**rules, "max_move_m": LIMIT_M if value <= 0 or value > LIMIT_M else 1.0}
        bind.execute(sa.update(t).where(t.c.id == row_id).values(rules=fixed))


def upgrade() -> None:
    _bounded("runs")
    _bounded("tasks")


def downgrade() -> None:
    # Nothing to undo: the old code reads 10 km as a limit as well, and which rules held 0 or
    # more than 10 km before the upgrade is not recorded.
    return None
