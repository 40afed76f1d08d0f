"""Assemble a ``PoseRun`` from parsed columns and turn invariant breaks into file/line errors."""

from __future__ import annotations

from typing import Callable

import numpy as np

from posefix.core.run import PoseRun, RunValidationError, validate_run
from posefix.io.errors import RunFormatError
from posefix.io.orientation import derive_heading_quaternions, warn_orientation_derived

# The name each format uses for a PoseRun field, for messages.
DEFAULT_FIELD_NAMES = {
    "t_s": "t", "lat_deg": "lat", "lon_deg": "lon", "alt_m": "alt",
    "q_body_to_enu_wxyz": "qw,qx,qy,qz",
    "gnss_lat_deg": "gnss_lat", "gnss_lon_deg": "gnss_lon", "gnss_alt_m": "gnss_alt",
}


def build_run(
    source: str,
    t_s: np.ndarray,
    lat_deg: np.ndarray,
    lon_deg: np.ndarray,
    alt_m: np.ndarray,
    q_body_to_enu_wxyz: np.ndarray | None,
    *,
    line_of_row: Callable[[int], int | None] = lambda i: None,
    field_names: dict[str, str] | None = None,
    gnss: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    images: list[str] | None = None,
    extra: dict[str, np.ndarray] | None = None,
) -> PoseRun:
    """Validate and build a run; derive heading when ``q_body_to_enu_wxyz`` is None.

    Raises ``RunFormatError`` naming ``source``, the line of the offending row (via
    ``line_of_row``, 0-based row -> 1-based line) and the field as the format calls it.
    """
    names = dict(DEFAULT_FIELD_NAMES)
    names.update(field_names or {})
    derived = q_body_to_enu_wxyz is None
    n = int(np.shape(t_s)[0])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if derived else np.asarray(q_body_to_enu_wxyz, dtype=float)
    run = PoseRun(
        t_s=np.asarray(t_s, dtype=float),
        lat_deg=np.asarray(lat_deg, dtype=float),
        lon_deg=np.asarray(lon_deg, dtype=float),
        alt_m=np.asarray(alt_m, dtype=float),
        q_body_to_enu_wxyz=q,
        gnss_lat_deg=None if gnss is None else np.asarray(gnss[0], dtype=float),
        gnss_lon_deg=None if gnss is None else np.asarray(gnss[1], dtype=float),
        gnss_alt_m=None if gnss is None else np.asarray(gnss[2], dtype=float),
        images=images,
        extra=extra or {},
        orientation_derived=derived,
        source=str(source),
    )
    try:
        norm = validate_run(run)
    except RunValidationError as exc:
        line = None if exc.row is None else line_of_row(exc.row)
        raise RunFormatError(source, line, names.get(exc.field, exc.field), exc.message) from None
    if derived:
        q = derive_heading_quaternions(run.t_s, run.lat_deg, run.lon_deg, run.alt_m)
        warn_orientation_derived(str(source))
        from dataclasses import replace

        run = replace(run, q_body_to_enu_wxyz=q)
    else:
        # Accept small rounding in the file; store exact unit quaternions.
        run = _with_normalised_q(run, norm)
    return run


def _with_normalised_q(run: PoseRun, norm: np.ndarray | None = None) -> PoseRun:
    """``run`` with its quaternions divided by their norms (``norm``: already computed, (n,))."""
    from dataclasses import replace

    q = run.q_body_to_enu_wxyz
    if norm is None:
        norm = np.linalg.norm(q, axis=1)
    return replace(run, q_body_to_enu_wxyz=q / norm[:, None])
