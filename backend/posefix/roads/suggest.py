"""Suggestions for a vehicle run: the road-network matcher, and the drivable-area grid where
the roads cannot serve.

The road matcher (:mod:`posefix.roads.match`) is the default: candidate projections within
``RADIUS_M`` of each keyframe, tens of thousands of keyframes a second. The grid
(:func:`posefix.mapmatch.suggest.suggest_for_run`, a CRF over a raster of the drivable
area, about 600 keyframes a second) has no search radius, so it takes over when fewer than
``MIN_NEAR_SHARE`` of the keyframes have a road within reach (a run mostly in a car park or
a gap of the extract), and when asked for by name.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posefix.mapmatch.suggest import Suggestions, suggest_for_run
from posefix.roads.match import FewRoadsNear, match_on_roads

__all__ = ["MATCHERS", "MIN_NEAR_SHARE", "suggest_vehicle_run"]

MATCHERS = ("roads", "grid")
MIN_NEAR_SHARE = 0.5  # a road within reach of most keyframes: otherwise the run is not on the mapped roads


def suggest_vehicle_run(lon_deg: np.ndarray, lat_deg: np.ndarray, q_body_to_enu_wxyz: np.ndarray,
                        osm_path: str | Path, t_s: np.ndarray | None = None, matcher: str = "roads",
                        cell_m: float = 2.0, index: np.ndarray | None = None) -> Suggestions:
    """Suggested positions for the keyframes (module docstring); ``Suggestions.matcher`` says
    which matcher answered. ``cell_m`` is the grid's cell size."""
    if matcher not in MATCHERS:
        raise ValueError(f"field matcher: {matcher!r} is not one of {', '.join(MATCHERS)}")
    if matcher == "roads":
        try:
            return match_on_roads(lon_deg, lat_deg, q_body_to_enu_wxyz, osm_path, index=index, t_s=t_s,
                                  min_near_share=MIN_NEAR_SHARE)
        except FewRoadsNear:
            pass  # off the network (yards, car parks, indoors): the grid answers
    return suggest_for_run(lon_deg, lat_deg, q_body_to_enu_wxyz, osm_path, index=index, cell_m=cell_m)
