"""Drift: the GNSS bias the edits reveal, and what it does to the location term.

One module per model over a shared bottom (``base``: the estimate, the edit offsets
``d_k = g~(t_k) - c_k``, white sigma, keyframe means):

* ``bias``     the Gauss-Markov bias of the fixes, smoothed over the edit times;
* ``steps``    persistent steps of the fix against the locally rigid pose (canyon offsets);
* ``levels``   the fix's piecewise-constant level beside a pose that bridged those steps;
* ``bends``    edits the reported shape cannot join (the pose dragged by its GNSS);
* ``estimate`` the three location-term models put together (``estimate_drift``).

Each module opens with the equations it implements.
"""

from posefix.core.drift.base import (
    MEDIAN_EFFICIENCY,
    DriftEstimate,
    DriftParams,
    edit_offsets,
    fill_gaps,
    keyframe_means,
    keyframes_in,
    no_drift,
    white_sigma,
)
from posefix.core.drift.bends import TRANSIENT_CHI2, edit_bends, gnss_transient, shape_change_evidence
from posefix.core.drift.bias import bias_at, estimate_walk, local_walk, smooth_gauss_markov
from posefix.core.drift.estimate import estimate_drift
from posefix.core.drift.levels import (
    LEVEL_TAPER_KEYFRAMES,
    GnssLevels,
    find_level_jumps,
    gnss_levels,
    level_bias,
    level_breaks,
    levels_bridged,
    levels_near_new_edits,
    open_sky_information,
    solve_levels,
)
from posefix.core.drift.steps import GnssSteps, gnss_steps, step_window, steps_confirmed_by_edits, suspect_intervals

__all__ = [
    "MEDIAN_EFFICIENCY", "TRANSIENT_CHI2", "LEVEL_TAPER_KEYFRAMES", "DriftEstimate", "DriftParams", "GnssLevels",
    "GnssSteps", "bias_at", "edit_bends", "edit_offsets", "estimate_drift", "estimate_walk", "fill_gaps",
    "find_level_jumps", "gnss_levels", "gnss_steps", "gnss_transient", "keyframe_means", "keyframes_in",
    "level_bias", "level_breaks", "levels_bridged", "levels_near_new_edits", "local_walk", "no_drift",
    "open_sky_information", "shape_change_evidence", "smooth_gauss_markov", "solve_levels", "step_window",
    "steps_confirmed_by_edits", "suspect_intervals", "white_sigma",
]
