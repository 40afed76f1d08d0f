"""tasks: tasks (HITs), task runs, assignments (leases), transition history, operator
profiles and qualifications, gold runs

Revision ID: b8f72baccca7
Revises: b7e1c0a2f3d4
Create Date: 2026-11-22 03:12:14.263615
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = 'b8f72baccca7'
down_revision = 'b7e1c0a2f3d4'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table('operator_profiles',
    sa.Column('user_id', sa.Integer(), nullable=False),
    sa.Column('home_lon', sa.Float(), nullable=True),
    sa.Column('home_lat', sa.Float(), nullable=True),
    sa.Column('home_radius_m', sa.Float(), nullable=True),
    sa.Column('home_polygon', sa.JSON(), nullable=True),
    sa.Column('last_request_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['user_id'], ['users.id'], name=op.f('fk_operator_profiles_user_id_users'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('user_id', name=op.f('pk_operator_profiles'))
    )
    op.create_table('operator_qualifications',
    sa.Column('user_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=64), nullable=False),
    sa.Column('value', sa.Float(), nullable=False),
    sa.Column('granted_by', sa.Integer(), nullable=True),
    sa.Column('granted_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('detail', sa.JSON(), nullable=True),
    sa.ForeignKeyConstraint(['granted_by'], ['users.id'], name=op.f('fk_operator_qualifications_granted_by_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['user_id'], ['users.id'], name=op.f('fk_operator_qualifications_user_id_users'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('user_id', 'name', name=op.f('pk_operator_qualifications'))
    )
    op.create_table('tasks',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('title', sa.String(length=200), nullable=False),
    sa.Column('instructions', sa.Text(), nullable=False),
    sa.Column('reward_cents', sa.Integer(), nullable=False),
    sa.Column('currency', sa.String(length=3), nullable=False),
    sa.Column('assignments_per_run', sa.Integer(), nullable=False),
    sa.Column('lease_s', sa.Integer(), nullable=False),
    sa.Column('lifetime_s', sa.Integer(), nullable=False),
    sa.Column('auto_approval_delay_s', sa.Integer(), nullable=False),
    sa.Column('priority', sa.Integer(), nullable=False),
    sa.Column('max_active_leases', sa.Integer(), nullable=False),
    sa.Column('rules', sa.JSON(), nullable=True),
    sa.Column('requirements', sa.JSON(), nullable=False),
    sa.Column('conflict_distance_m', sa.Float(), nullable=False),
    sa.Column('conflict_keyframes', sa.Integer(), nullable=False),
    sa.Column('conflict_edit_m', sa.Float(), nullable=False),
    sa.Column('conflict_policy', sa.String(length=16), nullable=False),
    sa.Column('max_extra_assignments', sa.Integer(), nullable=False),
    sa.Column('is_test', sa.Boolean(), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('requester_id', sa.Integer(), nullable=True),
    sa.Column('client_token', sa.String(length=64), nullable=True),
    sa.Column('request_hash', sa.String(length=64), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('expires_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['requester_id'], ['users.id'], name=op.f('fk_tasks_requester_id_users'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_tasks')),
    sa.UniqueConstraint('requester_id', 'client_token', name=op.f('uq_tasks_requester_id_client_token'))
    )
    with op.batch_alter_table('tasks', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_tasks_requester_id'), ['requester_id'], unique=False)
        batch_op.create_index('ix_tasks_status_priority', ['status', 'priority'], unique=False)

    op.create_table('gold_runs',
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('truth_file', sa.String(length=255), nullable=False),
    sa.Column('is_test', sa.Boolean(), nullable=False),
    sa.Column('pass_error_m', sa.Float(), nullable=False),
    sa.Column('created_by', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['created_by'], ['users.id'], name=op.f('fk_gold_runs_created_by_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['run_id'], ['runs.id'], name=op.f('fk_gold_runs_run_id_runs'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('run_id', name=op.f('pk_gold_runs'))
    )
    op.create_table('task_events',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('task_id', sa.Integer(), nullable=False),
    sa.Column('assignment_id', sa.Integer(), nullable=True),
    sa.Column('task_run_id', sa.Integer(), nullable=True),
    sa.Column('entity', sa.String(length=16), nullable=False),
    sa.Column('from_status', sa.String(length=16), nullable=True),
    sa.Column('to_status', sa.String(length=16), nullable=False),
    sa.Column('actor_id', sa.Integer(), nullable=True),
    sa.Column('at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('reason', sa.String(length=64), nullable=True),
    sa.Column('detail', sa.JSON(), nullable=True),
    sa.ForeignKeyConstraint(['actor_id'], ['users.id'], name=op.f('fk_task_events_actor_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['task_id'], ['tasks.id'], name=op.f('fk_task_events_task_id_tasks'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_task_events'))
    )
    with op.batch_alter_table('task_events', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_task_events_assignment_id'), ['assignment_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_task_events_task_id'), ['task_id'], unique=False)

    op.create_table('task_runs',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('task_id', sa.Integer(), nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('is_gold', sa.Boolean(), nullable=False),
    sa.Column('centre_lon', sa.Float(), nullable=False),
    sa.Column('centre_lat', sa.Float(), nullable=False),
    sa.Column('wanted', sa.Integer(), nullable=False),
    sa.Column('extra_added', sa.Integer(), nullable=False),
    sa.Column('base_revision', sa.Integer(), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('consensus', sa.JSON(), nullable=True),
    sa.Column('disagreement_m', sa.JSON(), nullable=True),
    sa.Column('conflicts', sa.JSON(), nullable=True),
    sa.Column('merge_batch_id', sa.Integer(), nullable=True),
    sa.Column('merged_revision', sa.Integer(), nullable=True),
    sa.Column('merge_detail', sa.JSON(), nullable=True),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['run_id'], ['runs.id'], name=op.f('fk_task_runs_run_id_runs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['task_id'], ['tasks.id'], name=op.f('fk_task_runs_task_id_tasks'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_task_runs')),
    sa.UniqueConstraint('task_id', 'run_id', name=op.f('uq_task_runs_task_id_run_id'))
    )
    with op.batch_alter_table('task_runs', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_task_runs_run_id'), ['run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_task_runs_task_id'), ['task_id'], unique=False)

    op.create_table('assignments',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('task_id', sa.Integer(), nullable=False),
    sa.Column('task_run_id', sa.Integer(), nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=True),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('base_revision', sa.Integer(), nullable=True),
    sa.Column('leased_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('lease_expires_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('submitted_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('edit_set', sa.JSON(), nullable=True),
    sa.Column('comment', sa.Text(), nullable=True),
    sa.Column('corrected', sa.JSON(), nullable=True),
    sa.Column('evaluated_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('gold_error_m', sa.Float(), nullable=True),
    sa.Column('consensus_error_m', sa.Float(), nullable=True),
    sa.Column('auto_approve_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('reviewed_by', sa.Integer(), nullable=True),
    sa.Column('reviewed_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('feedback', sa.Text(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['operator_id'], ['users.id'], name=op.f('fk_assignments_operator_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['reviewed_by'], ['users.id'], name=op.f('fk_assignments_reviewed_by_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['run_id'], ['runs.id'], name=op.f('fk_assignments_run_id_runs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['task_id'], ['tasks.id'], name=op.f('fk_assignments_task_id_tasks'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['task_run_id'], ['task_runs.id'], name=op.f('fk_assignments_task_run_id_task_runs'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_assignments')),
    sa.UniqueConstraint('operator_id', 'run_id', name=op.f('uq_assignments_operator_id_run_id'))
    )
    with op.batch_alter_table('assignments', schema=None) as batch_op:
        batch_op.create_index('ix_assignments_auto_approve', ['status', 'auto_approve_at'], unique=False)
        batch_op.create_index('ix_assignments_lease', ['status', 'lease_expires_at'], unique=False)
        batch_op.create_index('ix_assignments_operator_status', ['operator_id', 'status'], unique=False)
        batch_op.create_index('ix_assignments_pool', ['status', 'task_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_assignments_run_id'), ['run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_assignments_task_run_id'), ['task_run_id'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('assignments', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_assignments_task_run_id'))
        batch_op.drop_index(batch_op.f('ix_assignments_run_id'))
        batch_op.drop_index('ix_assignments_pool')
        batch_op.drop_index('ix_assignments_operator_status')
        batch_op.drop_index('ix_assignments_lease')
        batch_op.drop_index('ix_assignments_auto_approve')

    op.drop_table('assignments')
    with op.batch_alter_table('task_runs', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_task_runs_task_id'))
        batch_op.drop_index(batch_op.f('ix_task_runs_run_id'))

    op.drop_table('task_runs')
    with op.batch_alter_table('task_events', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_task_events_task_id'))
        batch_op.drop_index(batch_op.f('ix_task_events_assignment_id'))

    op.drop_table('task_events')
    op.drop_table('gold_runs')
    with op.batch_alter_table('tasks', schema=None) as batch_op:
        batch_op.drop_index('ix_tasks_status_priority')
        batch_op.drop_index(batch_op.f('ix_tasks_requester_id'))

    op.drop_table('tasks')
    op.drop_table('operator_qualifications')
    op.drop_table('operator_profiles')
