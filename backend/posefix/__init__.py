"""posefix: crowdsourced correction of vehicle and device trajectories."""

__version__ = "0.1.0"
