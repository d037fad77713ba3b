"""Dashboard sessions hold an opaque token, not an API key.

Drops the old sessions' own admin keys ("dashboard-session of ..." rows of api_keys): their cookies
carried them readable and they worked as Bearer keys, so every one of them is revoked here.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: Union[str, Sequence[str], None] = "0002"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

OLD_SESSION_KEYS = "SELECT id FROM api_keys WHERE name LIKE 'dashboard-session%'"


def upgrade() -> None:
    op.create_table(
        "admin_sessions",
        sa.Column("token_sha256", sa.String(64), primary_key=True),
        sa.Column("key_id", sa.Integer, sa.ForeignKey("api_keys.id", ondelete="CASCADE")),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_index("ix_admin_sessions_key_id", "admin_sessions", ["key_id"])
    op.create_index("ix_admin_sessions_expires_at", "admin_sessions", ["expires_at"])
    # A journey uploaded with a leaked session key stays, owned like the environment's admin key's.
    op.execute(f"UPDATE journeys SET owner_key_id = NULL WHERE owner_key_id IN ({OLD_SESSION_KEYS})")
    op.execute("DELETE FROM api_keys WHERE name LIKE 'dashboard-session%'")


def downgrade() -> None:
    op.drop_table("admin_sessions")
