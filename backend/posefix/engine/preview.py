"""The live-drag preview: what the server answers while an operator drags a keyframe.

A drag is a batch on a base revision whose exact solution is known (``base``).  The drift
estimate of the new edit set reaches the whole run (one edit showing a GNSS bias
down-weights every fix), which would make every frame of a drag a full solve.  The preview
therefore blends, per keyframe i at distance n_i (keyframes) from the nearest edit that
differs from the base revision's,

    w_i = clip((far - n_i) / (far - near), 0, 1),   (near, far) = LEVEL_TAPER_KEYFRAMES
    x_i = w_i x_i,new + (1 - w_i) x_i,base

for the drift's bias, its sigma and the location weight (the GNSS levels inside
``estimate_drift`` taper with the same (near, far)); then a local solve (``window``) from the
previous frame of the drag re-optimises only around the drag.  Near the drag the terms are
those the commit will see, so the dragged keyframe lands where the commit puts it; the
commit's full solve re-estimates the drift over the whole run.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from posefix.core.drift import LEVEL_TAPER_KEYFRAMES, DriftEstimate, DriftParams
from posefix.engine.edits import Edit, Edits, accepted_batch, check_batch, targets_enu
from posefix.engine.results import Preview, Solution


def taper(k: int, changed: np.ndarray) -> np.ndarray:
    """(k,) weight of the new estimate: 1 within ``near`` keyframes of a changed edit, 0 beyond ``far``."""
    near, far = LEVEL_TAPER_KEYFRAMES
    dist = np.min(np.abs(np.arange(k)[:, None] - np.asarray(changed)[None, :]), axis=1)
    return np.clip((far - dist) / (far - near), 0.0, 1.0)


def local_drift(problem, edits: Edits, base: Solution) -> DriftEstimate | None:
    """The drift estimate of ``edits`` near the keyframes whose edits differ from the base
    solution's, tapering to the base solution's estimate further away (``taper``).

    Only on the default keyframes with none removed: with deleted keyframes the base
    estimate no longer lines up with the solve's rows, and None lets the solve estimate the
    drift over the keyframes that remain.
    """
    cfg = problem.cfg
    index = problem.keyframe_index
    k = len(index)
    if edits.deleted or not bool(np.all(base.active)) or len(base.drift.bias_sigma_m) != k:
        return None
    if not cfg.drift.enabled or not edits.moves:
        return base.drift
    edit_kf = edits.index
    base_kf = base.keyframes.edited
    new_kf = edit_kf[~base_kf[edit_kf]] if len(base_kf) == k else edit_kf
    # keyframes edited now and not in the base revision (being dragged); else all edited ones
    changed = new_kf if len(new_kf) else edit_kf
    new = problem.estimate_drift(index, edit_kf, targets_enu(problem, edits.moves), edits.has_alt,
                                 held=None if base.drift.loc_sigma_h_m is None or base.drift.tau_s <= 0
                                 else DriftParams.of(base.drift), edit_sigma_m=edits.sigma_m)
    w = taper(k, changed)
    b = base.drift
    return dataclasses.replace(
        new,
        bias_enu_m=w[:, None] * new.bias_enu_m + (1 - w[:, None]) * b.bias_enu_m,
        bias_sigma_m=w * new.bias_sigma_m + (1 - w) * b.bias_sigma_m,
        weight=w * new.weight + (1 - w) * b.weight,
        loc_sigma_h_m=(None if new.loc_sigma_h_m is None or b.loc_sigma_h_m is None
                       else w * new.loc_sigma_h_m + (1 - w) * b.loc_sigma_h_m),
    )


def preview_batch(problem, moves: list[Edit], deleted, base_edits: Edits, base: Solution,
                  warm: Solution | Callable[[Edits], Solution | None] | None = None) -> Preview:
    """A batch dragged on a base revision (edit set ``base_edits``, exact solution ``base``):
    the rules check it against the base's moves (refused moves are left out and listed,
    flagged ones kept), then a local solve answers it warm from ``warm`` (the previous frame
    of the same drag; or a function of the merged edit set that finds it) or ``base``."""
    check = check_batch(problem, problem.cfg.rules, base_edits, list(moves), list(deleted))
    merged = accepted_batch(base_edits, list(moves), list(deleted), check)
    if callable(warm):
        warm = warm(merged)
    drift = local_drift(problem, merged, base)
    sol = problem.solve_edits(merged, warm or base, local=True, drift=drift)
    window = sol.solver.extra.get("window")
    held = sol.solver.extra.get("window_held")
    near, far = LEVEL_TAPER_KEYFRAMES
    info = {
        "mode": "local" if held is not None else "full",
        "local": held is not None,
        "full_solve": held is None,
        "window": None if window is None else [int(window[0]), int(window[1])],
        "keyframes": int(len(sol.keyframes.index)),
        "drift": f"the new estimate within {near}-{far} keyframes of the drag, the base revision's beyond "
                 "(the commit re-estimates it over the whole run)",
        "exact": False,
    }
    lon, lat, _ = problem.lonlatalt(sol)
    return Preview(lon_deg=np.asarray(lon), lat_deg=np.asarray(lat), solution=sol, refusals=check.refusals,
                   flags=check.flags, edits=merged, info=info)
