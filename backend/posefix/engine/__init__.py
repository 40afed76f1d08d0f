"""The correction engine's Python API (used by the CLI, the server, notebooks).

>>> from posefix.io import read_run, read_edits
>>> from posefix.engine import CorrectionConfig, prepare, correct
>>> result = correct(read_run("drive.csv"), read_edits("edits.json"), CorrectionConfig())
>>> result.run, result.keyframes, result.solver, result.drift

One package, one seam: ``problem`` (a run prepared once, solved for any edit set),
``edits`` (one ``Edit``, one ``Edits`` set, converted once at the edge), ``preview`` (the
live drag the server answers), ``window`` (local solves), ``results`` (what comes back).
"""

from posefix.core.config import ConfigError, CorrectionConfig
from posefix.engine.edits import Edit, Edits
from posefix.core.terms import implausible_motion_m
from posefix.engine.problem import Problem, correct, prepare
from posefix.engine.results import Correction, EditRefusedError, Preview, Solution

__all__ = [
    "CorrectionConfig",
    "ConfigError",
    "Problem",
    "Solution",
    "Correction",
    "Preview",
    "EditRefusedError",
    "Edit",
    "Edits",
    "prepare",
    "correct",
    "implausible_motion_m",
]
