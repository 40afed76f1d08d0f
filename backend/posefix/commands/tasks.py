"""Commands of the 'tasks' area, registered on posefix.cli.app."""

from posefix.cli import app  # noqa: F401
