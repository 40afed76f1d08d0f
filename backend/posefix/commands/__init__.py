"""The command areas of the ``posefix`` CLI, assembled by ``posefix.cli``."""
