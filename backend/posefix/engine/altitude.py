"""The altitudes a correction may give: within what the input and the edits allow.

The solver works in one East-North-Up plane anchored at the run's first sample, and a 2-D
move leaves the vertical free.  A corrected pose's height is its reported height plus the
solution's up correction (``Problem.geodetic``), so the plane's curvature (a pose moved d
across it sits d^2 / (2 R) below the plane's height: 7.8 m at 10 km) never reaches the
altitudes; what is left to guard is the solve's own vertical answer.  So every solution is
checked: each corrected keyframe altitude must
lie within the range of the run's own altitudes (the reported poses and, where present, the
GNSS fixes) and the altitudes of 3-D edits, widened by ``SIGMAS`` vertical standard
deviations of a fix (the location term's ``sigma_v_m`` and the drift model's
``bias_sigma_m`` together): the most a correction can honestly move a pose off the input is
what it believes the input's vertical error to be.
"""

from __future__ import annotations

import numpy as np

from posefix.core.config import CorrectionConfig
from posefix.core.rules import Refusal
from posefix.core.run import PoseRun

REASON = "altitude_out_of_range"
SIGMAS = 3.0


def vertical_margin_m(cfg: CorrectionConfig) -> float:
    """How far (m) a corrected altitude may leave the input's range: ``SIGMAS`` sigmas of a fix."""
    return SIGMAS * float(np.hypot(cfg.location.sigma_v_m, cfg.drift.bias_sigma_m))


def altitude_band(run: PoseRun, edit_alt_m: np.ndarray, cfg: CorrectionConfig) -> tuple[float, float]:
    """(lowest, highest) altitude in metres a corrected pose of ``run`` may have."""
    parts = [np.asarray(run.alt_m, dtype=float), np.asarray(edit_alt_m, dtype=float).ravel()]
    if run.gnss_alt_m is not None:
        parts.append(np.asarray(run.gnss_alt_m, dtype=float))
    values = np.concatenate(parts)
    values = values[np.isfinite(values)]
    margin = vertical_margin_m(cfg)
    return float(values.min()) - margin, float(values.max()) + margin


def altitude_refusal(alt_m: np.ndarray, band: tuple[float, float], active: np.ndarray | None = None) -> Refusal | None:
    """The keyframe furthest outside ``band``, or None.

    alt_m : ndarray, shape (k,)
        Corrected keyframe altitudes, metres.
    active : ndarray of bool, shape (k,), optional
        Keyframes that took part in the solve (deleted ones are not judged).
    """
    alt = np.asarray(alt_m, dtype=float)
    lo, hi = band
    excess = np.maximum(lo - alt, alt - hi)
    excess = np.where(np.isfinite(alt), excess, np.inf)  # a non-finite altitude is never allowed
    if active is not None:
        excess = np.where(active, excess, -np.inf)
    worst = int(np.argmax(excess)) if len(alt) else 0
    if not len(alt) or excess[worst] <= 0.0:
        return None
    return Refusal(worst, REASON, (
        f"The correction would put keyframe {worst} at an altitude of {alt[worst]:.1f} m, outside the "
        f"{lo:.1f} to {hi:.1f} m that the run's altitudes and the edits allow: more than the input's "
        "vertical error; give the moves an altitude if the height should change."))
