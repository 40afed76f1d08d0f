"""CRF map matching (the MapCraft method): floor graphs, Viterbi tracking, learning.

Numerical core: numpy/scipy only (pillow for floor images and osmium for OSM extracts are
imported lazily by the readers that need them). See docs/mapmatch.md.
"""

from posefix.mapmatch.api import build_model, read_track_csv, train_model, track_walk_file, write_track_csv
from posefix.mapmatch.model import Model, load_model, save_model
from posefix.mapmatch.sensors import read_walk
from posefix.mapmatch.suggest import Suggestions, suggest_for_run
from posefix.mapmatch.tracker import Tracker, TrackResult, track_walk

__all__ = [
    "Model",
    "build_model",
    "load_model",
    "save_model",
    "train_model",
    "read_walk",
    "Tracker",
    "TrackResult",
    "track_walk",
    "track_walk_file",
    "write_track_csv",
    "read_track_csv",
    "suggest_for_run",
    "Suggestions",
]
