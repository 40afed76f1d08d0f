"""Routes: GET /users/{id}/activity (admin): one person's edits and reviews."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from posefix.audit.service import UserActivity, user_activity
from posefix.deps import AdminUser, SessionDep
from posefix.errors import NotFound, responses
from posefix.users import repository as users_repo

router = APIRouter()


@router.get("/users/{user_id}/activity", response_model=UserActivity, tags=["users"], responses=responses(401, 403, 404))
def get_user_activity(
    user_id: int, _admin: AdminUser, session: SessionDep, limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> UserActivity:
    """An admin's audit view of one person: the edits they submitted and the reviews they made, newest first."""
    user = users_repo.get_user(session, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    return user_activity(session, user.id, user.username, limit)
