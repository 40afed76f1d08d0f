"""Road-network map matching of vehicle runs (OpenStreetMap ways as line segments)."""

from posefix.roads.match import match_on_roads
from posefix.roads.network import RoadNetwork, road_network

__all__ = ["RoadNetwork", "match_on_roads", "road_network"]
