"""Road-network map matching of vehicle runs (OpenStreetMap ways as line segments)."""

from posefix.roads.match import FewRoadsNear, match_on_roads
from posefix.roads.network import RoadNetwork, road_network
from posefix.roads.suggest import suggest_vehicle_run

__all__ = ["FewRoadsNear", "RoadNetwork", "match_on_roads", "road_network", "suggest_vehicle_run"]
