"""The problem: a run prepared for correction, solved for any edit set.

``prepare(run, cfg)`` does the work that does not depend on the edits once (local frame,
keyframes, reported relative motion, the run's GNSS statistics) and returns a ``Problem``;
``solve`` / ``solve_edits`` re-optimise after each batch of edits, ``preview`` answers a
live drag at keyframe level (``engine.preview``), ``full_run`` propagates to every sample.

Frames: the optimisation runs in an East-North-Up frame anchored at the first sample
(exact, through ECEF).  A pose's quaternion in the run is relative to ENU at its own
position; it is rotated into the anchored frame for the optimisation and back on output.

Heights: the plane is level only at its origin, so a pose kept at plane height ``u`` while
moved ``d`` across it would rise ``≈ d²/(2R)`` above the ellipsoid (7.8 m at 10 km).  The
plane's up is therefore read as a correction, not a height: a corrected pose gets

    h = h~ + (u - u~),   (e, n) from the plane,

with ``h~, u~`` its reported ellipsoidal height and plane up (``geodetic``), and a 3-D edit's
vertical target is ``u~_k + (h_edit - h~_k)`` at its keyframe ``k`` (``targets``).  A 2-D move
then changes no height, and a 3-D edit's height is met exactly.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from posefix.core import geodesy
from posefix.core import rotations as rot
from posefix.core import terms as T
from posefix.core.config import CorrectionConfig
from posefix.core.drift import (
    DriftEstimate,
    DriftParams,
    GnssLevels,
    GnssSteps,
    edit_bends,
    estimate_drift,
    gnss_levels,
    gnss_steps,
    gnss_transient,
    no_drift,
    shape_change_evidence,
    step_window,
)
from posefix.core.keyframes import KeyframeSet, path_length_m, rows_of_keyframes, select_keyframes
from posefix.core.propagate import interpolate_rotations, propagate_corrections
from posefix.core.rules import EditRules, KeyframeMove, Refusal, check_edits
from posefix.core.run import PoseRun
from posefix.core.solver import solve_banded, solve_local_newton
from posefix.core.solver_reference import solve
from posefix.engine.altitude import altitude_band, altitude_refusal
from posefix.engine.calibrate import Calibration
from posefix.engine.choose import solve_calibrated
from posefix.engine.edits import Edit, Edits, targets_enu
from posefix.engine.naive import naive_solution
from posefix.engine.results import Correction, EditRefusedError, Preview, Solution
from posefix.engine.window import solve_window

# A full solve keeps the model of its edit-independent terms for the next local solve up to this
# many keyframes (about 105 doubles each: 3 MB at 3,600, 17 MB at 20,000; kept with the solution,
# and in the server's stored solution files); beyond, a local solve linearises its window
LINEARISE_MAX_KEYFRAMES = 20_000
# Newton steps a whole-run ``newton`` solve may take from another model's answer before it falls
# back to Levenberg-Marquardt (metres apart: a few more than a local solve's)
NEWTON_MAX_STEPS = 12


class Problem:
    """A run prepared for correction: local frame, keyframes, reported motion.

    Attributes
    ----------
    origin : geodesy.EnuOrigin        the anchor of the local frame (first sample).
    p_enu_m : (n,3)                   reported positions in the local frame, metres.
    q_wxyz : (n,4)                    reported orientations, body -> anchored ENU.
    g_enu_m : (n,3) or None           raw GNSS in the local frame (NaN where no fix).
    along_m : (n,)                    distance travelled along the reported track, metres.
    keyframe_index : (k,)             rows of the default keyframes (no edits).
    """

    def __init__(self, run: PoseRun, cfg: CorrectionConfig | None = None):
        self.run = run
        self.cfg = cfg or CorrectionConfig()
        self.origin = geodesy.EnuOrigin(float(run.lat_deg[0]), float(run.lon_deg[0]), float(run.alt_m[0]))
        self.p_enu_m = geodesy.geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, self.origin)
        self.g_enu_m = None
        if run.has_gnss:
            self.g_enu_m = geodesy.geodetic_to_enu(run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m, self.origin)
        self.along_m = path_length_m(self.p_enu_m)
        self._q_local = rot.normalize_quat(run.q_body_to_enu_wxyz)
        image_mask = None
        if self.cfg.keyframes.images and run.images is not None:
            image_mask = np.array([bool(s) for s in run.images])
        self._image_mask = image_mask
        self.keyframe_index = self.keyframes_for(np.zeros(0, dtype=np.int64))
        self.keyframe_index.flags.writeable = False  # shared by every solve on the default keyframes
        self._default_key = self.keyframe_index.tobytes()
        self._local_to_anchor: dict[bytes, np.ndarray] = {}
        self._static: dict[bytes, object] = {}

    # ----------------------------------------------------------------- keyframes and frames

    def keyframes_for(self, required_rows: np.ndarray) -> np.ndarray:
        """Keyframe rows given rows that must be keyframes (edited or deleted samples).

        The default keyframes are selected once; required rows are merged into them (and the
        default array itself is returned when they are all keyframes already, the usual case
        for edits made in the editor, so cached per-keyframe data stays valid).
        """
        required_rows = np.asarray(required_rows, dtype=np.int64)
        base = getattr(self, "keyframe_index", None)
        if base is None:
            kc = self.cfg.keyframes
            return select_keyframes(
                self.run.t_s, self.p_enu_m, kc.every_s, kc.every_m, self._image_mask, required_rows
            )
        if len(required_rows) == 0:
            return base
        if required_rows.min() < 0 or required_rows.max() >= self.run.n:
            raise ValueError(f"keyframe rows must lie in 0..{self.run.n - 1}")
        pos = np.minimum(np.searchsorted(base, required_rows), len(base) - 1)
        missing = required_rows[base[pos] != required_rows]
        if len(missing) == 0:
            return base
        return np.union1d(base, missing)

    def _rows_key(self, rows: np.ndarray) -> bytes:
        """Cache key of a set of rows: their bytes.  The default keyframes' is made once: a bytes
        object keeps its hash, and hashing 30 kB on every look-up of every solve adds up."""
        if rows is self.keyframe_index:
            return self._default_key
        return np.asarray(rows).tobytes()

    def local_to_anchor(self, rows: np.ndarray) -> np.ndarray:
        """(m,4) quaternions rotating ENU at each row's position into the anchored ENU frame."""
        key = self._rows_key(rows)
        if key not in self._local_to_anchor:
            R = geodesy.rotation_local_enu_to_origin_enu(self.run.lat_deg[rows], self.run.lon_deg[rows], self.origin)
            self._local_to_anchor[key] = rot.matrix_to_quat(R)
        return self._local_to_anchor[key]

    def anchored_quat(self, rows: np.ndarray) -> np.ndarray:
        """Reported orientations of rows, body -> anchored ENU, (m,4) (cached per row set: read only)."""
        key = ("q", self._rows_key(rows))
        q = self._local_to_anchor.get(key)
        if q is None:
            q = rot.quat_multiply(self.local_to_anchor(rows), self._q_local[rows])
            q.flags.writeable = False
            self._local_to_anchor[key] = q
        return q

    def to_enu(self, lon_deg, lat_deg, alt_m) -> np.ndarray:
        return geodesy.geodetic_to_enu(np.atleast_1d(lat_deg), np.atleast_1d(lon_deg), np.atleast_1d(alt_m), self.origin)

    def targets(self, lon_deg, lat_deg, alt_m, rows) -> np.ndarray:
        """(m,3) edit targets on run ``rows``: east/north of (lon, lat) at height ``alt_m`` (NaN: a
        2-D move, at the row's reported height); a 3-D move's up is the row's reported up plus the
        height change it asks for (see the module docstring), not the plane up of the point."""
        rows = np.asarray(rows, dtype=np.int64)
        alt = np.asarray(alt_m, dtype=float).reshape(-1)
        has_alt = np.isfinite(alt)
        alt = np.where(has_alt, alt, self.run.alt_m[rows])
        c = self.to_enu(lon_deg, lat_deg, alt) if len(rows) else np.zeros((0, 3))
        c[has_alt, 2] = self.p_enu_m[rows[has_alt], 2] + (alt[has_alt] - self.run.alt_m[rows[has_alt]])
        return c

    def geodetic(self, p_enu_m, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latitude, longitude (degrees), altitude (m) of corrected positions of run ``rows``: the
        reported height plus the solution's up correction, at the plane's east/north."""
        rows = np.asarray(rows, dtype=np.int64)
        p = np.asarray(p_enu_m, dtype=float).reshape(-1, 3)
        alt = self.run.alt_m[rows] + (p[:, 2] - self.p_enu_m[rows, 2])
        return geodesy.en_height_to_geodetic(p[:, :2], alt, self.origin, up_m=p[:, 2])

    # ----------------------------------------------------------------- terms

    def _static_terms(self, rows: np.ndarray) -> T.Terms:
        """Edit-independent parts of the terms on these keyframe rows (cached)."""
        key = self._rows_key(rows)
        cached = self._static.get(key)
        if cached is not None:
            return cached
        cfg = self.cfg
        p = self.p_enu_m[rows]
        step_m = np.linalg.norm(np.diff(p, axis=0), axis=1)
        dt_s = np.diff(self.run.t_s[rows])
        rc = cfg.relative
        var_rt = rc.sigma_t_floor_m**2 + rc.sigma_t_per_sqrt_s_m**2 * dt_s + (rc.sigma_t_per_m * step_m) ** 2
        sigma_rr = np.sqrt(rc.sigma_r_floor_rad**2 + rc.sigma_r_per_sqrt_s_rad**2 * dt_s)
        empty3 = np.zeros((0, 3))
        terms = T.build_terms(
            p, self.anchored_quat(rows), np.zeros(0, np.int64), empty3, empty3 + 1.0,
            np.zeros(0, np.int64), empty3, empty3 + 1.0, np.sqrt(var_rt), sigma_rr, cfg.gravity.sigma,
            loss=cfg.location.loss, loss_scale=cfg.location.loss_scale,
        )
        # sideways motion a vehicle cannot make is error, not motion (see terms.vehicle_motion): its
        # sigma grows by it; the steps without it are kept beside, for solves with edits
        delta, excess = T.vehicle_motion(terms.rel_delta_m, terms.rel_dR, dt_s, rc.max_lateral_speed_mps)
        terms = dataclasses.replace(terms, rel_w_t=1.0 / np.sqrt(var_rt + excess**2))
        if len(self._static) > 32:  # a few keyframe sets' worth (about six entries each)
            self._static.clear()
            self._local_to_anchor.clear()
        self._static[key] = terms
        self._static[("plausible", key)] = delta
        return terms

    def _gnss_steps(self, rows: np.ndarray, t_s: np.ndarray, p_rep: np.ndarray, g: np.ndarray) -> GnssSteps:
        """GNSS steps against the pose on these keyframes (cached: they depend on the run only)."""
        key = ("steps", self._rows_key(rows))
        if key not in self._static:
            self._static[key] = gnss_steps((g - p_rep)[:, :2], window=step_window(t_s))
        return self._static[key]

    def _shape_evidence(self, rows: np.ndarray, t_s: np.ndarray, static: T.Terms,
                        g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the reported pose's error most likely changed, per step (k-1,), and the GNSS
        transient statistic per keyframe (k,) (cached: they depend on the run only)."""
        key = ("evidence", self._rows_key(rows))
        if key not in self._static:
            rc = self.cfg.relative
            side = T.sideways_steps(static.rel_delta_m, static.rel_dR)[2]  # the reported steps
            dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
            n_short, n_long = (max(int(round(w / max(dt, 1e-9))), 1) for w in (rc.transient_short_s, rc.transient_long_s))
            transient = gnss_transient((g - static.p_rep_m)[:, :2], n_short, n_long)
            self._static[key] = (shape_change_evidence(transient, np.hypot(side[:, 0], side[:, 1])), transient)
        return self._static[key]

    def gnss_levels(self, rows: np.ndarray) -> GnssLevels | None:
        """The GNSS level model's data on these keyframe rows (drift.gnss_levels), from every
        sample's fix (cached: it depends on the run only); None without raw GNSS."""
        if self.g_enu_m is None:
            return None
        key = ("levels", self._rows_key(rows))
        if key not in self._static:
            u = self.g_enu_m[:, :2] - self.p_enu_m[:, :2]
            self._static[key] = gnss_levels(self.run.t_s, u, self.run.t_s[rows])
        return self._static[key]

    def _location_measurements(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Location measurements on these keyframe rows (k,3), which have a fix (k,), and the
        measurements with NaN rows where there is none (cached per row set: read only)."""
        key = ("loc", self._rows_key(rows))
        hit = self._static.get(key)
        if hit is None:
            g = self.p_enu_m[rows] if self.g_enu_m is None else self.g_enu_m[rows]
            has_fix = np.all(np.isfinite(g), axis=1)
            g_nan = np.where(has_fix[:, None], g, np.nan)
            for arr in (g, has_fix, g_nan):
                arr.flags.writeable = False
            hit = self._static[key] = (g, has_fix, g_nan)
        return hit

    def _reported_unit_quat(self, rows: np.ndarray) -> np.ndarray:
        """Reported orientations of these rows as the solver's unit quaternions (w >= 0), cached."""
        key = ("qrep", self._rows_key(rows))
        q = self._static.get(key)
        if q is None:
            q = self._static[key] = rot.normalize_quat(self.anchored_quat(rows))
        return q

    # ----------------------------------------------------------------- solving


    def estimate_drift(self, act_rows: np.ndarray, edit_kf: np.ndarray, edit_c_m: np.ndarray,
                       edit_has_alt: np.ndarray, held: DriftParams | None = None,
                       g_nan: np.ndarray | None = None, edit_sigma_m: np.ndarray | None = None) -> DriftEstimate:
        """The drift estimate (``drift.estimate_drift``) of edits at keyframes ``edit_kf`` (into
        ``act_rows``) with ENU targets ``edit_c_m``; ``held`` keeps a previous solve's parameters;
        ``edit_sigma_m`` (m,) the horizontal 1-sigma each edit carries (NaN: the configured one)."""
        cfg = self.cfg
        lc, uc = cfg.location, cfg.user
        t_act = self.run.t_s[act_rows]
        p_rep = self._static_terms(act_rows).p_rep_m
        if g_nan is None:
            g_nan = self._location_measurements(act_rows)[2]
        return estimate_drift(
            t_act, p_rep, g_nan, np.asarray(edit_kf, dtype=np.int64), np.asarray(edit_c_m, dtype=float).reshape(-1, 3),
            np.asarray(edit_has_alt, dtype=bool), lc.sigma_h_m, lc.sigma_v_m, self.edit_sigma_h(edit_sigma_m), uc.sigma_v_m,
            cfg.drift.bias_sigma_m, cfg.drift.bias_tau_s, cfg.drift.min_edits_for_estimate,
            held=held, steps=self._gnss_steps(act_rows, t_act, p_rep, g_nan),
            levels=lambda: self.gnss_levels(act_rows),
        )

    def edit_sigma_h(self, edit_sigma_m: np.ndarray | None) -> float | np.ndarray:
        """The horizontal 1-sigma per axis of each edit: the configured ``[user] sigma_h_m`` (a
        float: every edit an operator's click), or (m,) where edits carry their own (NaN: the
        configured one)."""
        default = self.cfg.user.sigma_h_m
        if edit_sigma_m is None:
            return default
        sig = np.asarray(edit_sigma_m, dtype=float).reshape(-1)
        return np.where(np.isfinite(sig), sig, default)

    def solve_rows(
        self,
        index: np.ndarray,
        edit_kf: np.ndarray,
        edit_c_m: np.ndarray,
        edit_has_alt: np.ndarray,
        deleted_kf: np.ndarray,
        warm_start: Solution | Correction | None = None,
        flags: list[Refusal] | None = None,
        local: bool = False,
        drift: DriftEstimate | None = None,
        plausible_steps: bool = False,
        calibration: Calibration | None = None,
        span: tuple[int, int] | None = None,
        newton: bool = False,
        edit_sigma_m: np.ndarray | None = None,
    ) -> Solution:
        """Optimise keyframes ``index`` with edits given as keyframe numbers and ENU targets.

        With ``local`` and a warm start on the same keyframes (a live drag, one more edit),
        the drift model keeps the previous solve's parameters and only the keyframes whose
        terms changed, plus ``window.LOCAL_MARGIN`` on each side, are re-optimised; the rest stay
        at the previous solution (the edit's effect beyond its neighbouring edits is
        negligible).  Without ``local`` the full problem is solved (from the warm start).
        ``drift`` (on the active keyframes) replaces the drift estimate: a live-drag preview
        keeps the base solution's, so a drag changes the terms only at the dragged keyframes.
        ``plausible_steps``: measure the relative terms on the plausible steps even without
        edits (as every solve with edits does; see ``drag_base``).
        ``newton`` (with a warm start on the same keyframes that kept its ``linearisation``):
        solve the whole run by Newton steps on that model (``solver.solve_local_newton``: only
        the location term re-modelled) instead of Levenberg-Marquardt, to within about a
        millimetre of the optimum horizontally (steps measured east/north: the height is not
        what it is for).  The held-out scoring of another candidate model starts from it
        (``engine.choose``); the result keeps the warm start's linearisation.
        ``edit_sigma_m`` (m,): the horizontal 1-sigma per axis each edit carries (NaN or None:
        ``[user] sigma_h_m``); an edit is a soft constraint held to its sigma, in the user term,
        the drift model and the edit bends alike.
        """
        cfg = self.cfg
        k = len(index)
        deleted = np.zeros(k, dtype=bool)
        deleted[np.asarray(deleted_kf, dtype=np.int64)] = True
        remove = cfg.rules.deleted == "remove"
        active = ~deleted if remove else np.ones(k, dtype=bool)
        act_rows = index if active.all() else index[active]  # the same array: cached data keyed on it
        new_number = np.cumsum(active) - 1  # keyframe number -> active number
        static = self._static_terms(act_rows)
        t_act = self.run.t_s[act_rows]
        p_rep = static.p_rep_m
        warm_sol = None if warm_start is None else (
            warm_start.solution if isinstance(warm_start, Correction) else warm_start)
        same_rows = warm_sol is not None and _same_rows(warm_sol, act_rows)
        # the model the run's own held-out edits chose (engine.calibrate); a local solve (a live
        # drag, one more edit) keeps the warm solution's, as the preview keeps its drift
        calib = calibration
        if calib is None and local and same_rows:
            calib = warm_sol.drift.calibration
        if calib is not None and calib.model == "naive":
            return naive_solution(self, index, edit_kf, edit_c_m, edit_has_alt, deleted_kf, flags, calib)
        sigma_u_h = self.edit_sigma_h(edit_sigma_m)
        g, has_fix, g_nan = self._location_measurements(act_rows)
        if not remove and np.any(deleted):
            has_fix = has_fix & ~deleted[active]  # a flagged (deleted) keyframe keeps no location term
            g_nan = np.where(has_fix[:, None], g, np.nan)
        edit_kf = np.asarray(edit_kf, dtype=np.int64)
        e_act = new_number[edit_kf]
        edit_c_m = np.asarray(edit_c_m, dtype=float).reshape(-1, 3)
        edit_has_alt = np.asarray(edit_has_alt, dtype=bool)
        lc, uc = cfg.location, cfg.user
        held = None
        if local and same_rows and warm_sol.drift.tau_s > 0:
            held = DriftParams.of(warm_sol.drift)
        relative_only = calib is not None and calib.model == "relative"
        plain = calib is not None and calib.model in ("relative", "plain")
        if plain:
            # no location term (the drift model has nothing to act on), or the plain one: fixes at
            # their configured sigma, without the drift model and the edit bends
            drift = no_drift(len(act_rows))
        elif drift is not None:
            if len(drift.bias_sigma_m) != len(act_rows):
                raise ValueError(f"drift is for {len(drift.bias_sigma_m)} keyframes, the solve has {len(act_rows)}")
        elif cfg.drift.enabled and len(e_act):
            drift = self.estimate_drift(act_rows, e_act, edit_c_m, edit_has_alt, held, g_nan, edit_sigma_m)
        else:
            drift = no_drift(len(act_rows))
        if calib is not None:
            drift = dataclasses.replace(drift, calibration=calib)
        loc_idx = np.flatnonzero(has_fix)
        rel_w_t, dragged = static.rel_w_t, np.zeros(len(act_rows), dtype=bool)
        if cfg.relative.edit_bend_chi2 > 0 and len(e_act) > 1 and not plain:
            # edits the reported shape cannot join loosen the relative terms between them where
            # the pose was most likely dragged, and the fixes that dragged it drop out (drift.edit_bends)
            evidence, transient = self._shape_evidence(act_rows, t_act, static, g_nan)
            extra_rel, dragged = edit_bends(p_rep, 1.0 / static.rel_w_t**2, evidence, e_act, edit_c_m,
                                            sigma_u_h, cfg.relative.edit_bend_chi2, g_nan, lc.sigma_h_m,
                                            transient=transient)
            if np.any(extra_rel > 0):
                rel_w_t = 1.0 / np.sqrt(1.0 / static.rel_w_t**2 + extra_rel)
        at = slice(None) if len(loc_idx) == len(act_rows) else loc_idx  # every keyframe located: no gathers
        if drift.loc_sigma_h_m is not None:  # the GNSS level model's own measurements (drift.gnss_levels)
            sigma_h = drift.loc_sigma_h_m[at]
        else:
            sigma_h = np.sqrt(lc.sigma_h_m**2 + drift.bias_sigma_m[at] ** 2)
        loc_sigma = np.stack([sigma_h, sigma_h, np.full(len(loc_idx), lc.sigma_v_m)], axis=1)
        loc_sigma[dragged[at]] = np.inf  # weight 0: kept in place so local solves see the same located set
        if relative_only:  # pose and edits only: every location term at weight 0, kept in place likewise
            loc_sigma[:] = np.inf
        loc_g = g[at] - drift.bias_enu_m[at]
        user_sigma = np.tile([uc.sigma_h_m, uc.sigma_h_m, uc.sigma_v_m], (len(e_act), 1))
        if edit_sigma_m is not None:
            user_sigma[:, :2] = sigma_u_h[:, None]
        user_sigma[~edit_has_alt, 2] = np.inf
        c = edit_c_m.copy()
        c[~edit_has_alt, 2] = p_rep[e_act[~edit_has_alt], 2]  # unused (zero weight), kept finite
        terms = dataclasses.replace(
            static,
            loc_idx=loc_idx, loc_g_m=loc_g, loc_w=1.0 / loc_sigma,
            user_idx=e_act, user_c_m=c, user_w=1.0 / user_sigma, rel_w_t=rel_w_t,
            # with edits, the relative terms measure the reported steps without the sideways motion
            # a vehicle cannot make; without any, the run stays exactly as reported
            rel_delta_m=(self._static[("plausible", self._rows_key(act_rows))] if len(e_act) or plausible_steps
                         else static.rel_delta_m),
        )
        if local and same_rows and len(e_act) and warm_sol.terms is not None \
                and not warm_sol.keyframes.edited.any() and not T.same_array(warm_sol.terms.rel_delta_m, terms.rel_delta_m):
            # an unedited warm start measured the steps as reported; these edits switch every
            # implausible step along the run to its plausible form: start from that problem's
            # solution (solved once, cached) so only the edits' neighbourhood changes
            warm_sol = warm_start = self.drag_base(warm_sol)
        x0 = self._warm_state(act_rows, p_rep, warm_start)
        result = None
        lin = None
        if local and same_rows and warm_sol.terms is not None and cfg.solver.method == "banded":
            lin = warm_sol.linearisation
            if lin is not None and not lin.matches(terms):
                lin = None
            x, result = solve_window(terms, warm_sol.terms, x0, warm_sol.solver, cfg.solver, lin, span)
        elif newton and same_rows and warm_sol.linearisation is not None and cfg.solver.method == "banded" \
                and warm_sol.linearisation.matches(terms):
            lin = warm_sol.linearisation
            # chord steps from the second on: a whole run's factorisation is the step's main cost,
            # and the location term's Hessian changes little as the fixes' robust weights settle
            out = solve_local_newton(terms, x0, max_steps=NEWTON_MAX_STEPS, linearisation=lin.window(0, len(act_rows) - 1),
                                     step_axes=2, chord_after_m=np.inf)
            if out is not None:
                x, result = out
        if result is None:
            if cfg.solver.method == "banded":
                x, result = solve_banded(terms, x0, cfg.solver.max_iterations, cfg.solver.ftol,
                                         linearise=len(act_rows) <= LINEARISE_MAX_KEYFRAMES)
                lin = result.extra.pop("linearisation", None)
            else:
                x, result = solve(terms, x0, cfg.solver.method, cfg.solver.max_iterations, cfg.solver.ftol)
                lin = None
        q_rep = self._reported_unit_quat(act_rows)
        window = result.extra.get("window_held")
        if window is not None and T.same_array(warm_sol.keyframes.index, index) \
                and np.array_equal(warm_sol.active, active):
            # a local solve moved only keyframes lo..hi: start from the previous answer
            lo, hi = window
            p_all = warm_sol.keyframes.p_enu_m.copy()
            q_all = warm_sol.keyframes.q_wxyz.copy()
            xs = x.reshape(-1, 6)
            rows_w = np.flatnonzero(active)[lo:hi + 1]
            p_all[rows_w] = xs[lo:hi + 1, :3]
            q_all[rows_w] = rot.quat_multiply(q_rep[lo:hi + 1], rot.exp_quat(xs[lo:hi + 1, 3:]))
        else:
            p_sol, theta = T.split_state(x)
            q_sol = rot.quat_multiply(q_rep, rot.exp_quat(theta))
            # keyframes outside the optimisation keep their reported pose (they leave the output)
            p_all = self.p_enu_m[index]
            q_all = self.anchored_quat(index).copy()
            p_all[active], q_all[active] = p_sol, q_sol
        edited = np.zeros(k, dtype=bool)
        edited[edit_kf] = True
        if warm_sol is not None and warm_sol.keyframes.index is index:  # the same keyframes: share what is read only
            t_kf, p_rep_kf = warm_sol.keyframes.t_s, warm_sol.keyframes.reported_p_enu_m
        else:
            t_kf, p_rep_kf = self.run.t_s[index], self.p_enu_m[index]
        kfs = KeyframeSet(
            index=index, t_s=t_kf, p_enu_m=p_all, q_wxyz=q_all,
            reported_p_enu_m=p_rep_kf, reported_q_wxyz=self.anchored_quat(index),
            edited=edited, deleted=deleted,
        )
        return Solution(kfs, result, drift, x, active, list(flags or []), terms, lin)

    def drag_base(self, sol: Solution) -> Solution:
        """The solution a local solve with edits starts from: ``sol`` itself, or, when ``sol`` is
        unedited and the run has steps a vehicle cannot make (``terms.vehicle_motion``), the
        same unedited problem with its relative terms on the plausible steps, as any edit
        measures them.  Solved once per ``sol`` (a full solve) and cached: a server warms it
        with the revision so the first drag of an unedited run stays a local solve.
        """
        if sol.terms is None or sol.keyframes.edited.any():
            return sol
        act_rows = sol.keyframes.index if sol.active.all() else sol.keyframes.index[sol.active]
        self._static_terms(act_rows)
        if T.same_array(self._static[("plausible", self._rows_key(act_rows))], sol.terms.rel_delta_m):
            return sol  # every step plausible (or already measured so)
        key = ("drag_base", self._rows_key(act_rows))
        cached = self._static.get(key)
        if cached is None or cached[0] is not sol:
            none3 = np.zeros((0, 3))
            base = self.solve_rows(sol.keyframes.index, np.zeros(0, np.int64), none3, np.zeros(0, bool),
                                   np.flatnonzero(sol.keyframes.deleted), warm_start=sol, flags=sol.flags,
                                   plausible_steps=True)
            cached = self._static[key] = (sol, base)
        return cached[1]


    def _warm_state(self, act_rows: np.ndarray, p_rep: np.ndarray, warm) -> np.ndarray | None:
        """Initial state from a previous solution: its corrections interpolated in time."""
        if warm is None:
            return None
        sol = warm.solution if isinstance(warm, Correction) else warm
        prev_rows = sol.keyframes.index[sol.active]
        prev = sol.x.reshape(-1, 6)
        if len(prev_rows) == len(act_rows) and np.array_equal(prev_rows, act_rows):
            return sol.x.copy()
        t_prev = self.run.t_s[prev_rows]
        t_new = self.run.t_s[act_rows]
        dp = prev[:, :3] - self.p_enu_m[prev_rows]
        x0 = np.empty((len(act_rows), 6))
        for j in range(3):
            x0[:, j] = p_rep[:, j] + np.interp(t_new, t_prev, dp[:, j])
            x0[:, 3 + j] = np.interp(t_new, t_prev, prev[:, 3 + j])
        return x0.ravel()

    def solve(self, edits=None, warm_start: Solution | Correction | None = None, local: bool = False) -> Solution:
        """Optimise with an ``EditSet`` (edits by sample time); edited samples become keyframes.

        Raises ``EditMatchError`` for a time naming no sample and ``EditRefusedError`` when
        the edit rules refuse a move.
        """
        index, edit_kf, c_m, has_alt, deleted_kf = self._resolve_edit_set(edits)
        flags = self._check_rules(index, edit_kf, c_m, deleted_kf)
        if local:
            sol = self.solve_rows(index, edit_kf, c_m, has_alt, deleted_kf, warm_start, flags, local=True)
        else:
            sol = solve_calibrated(self, index, edit_kf, c_m, has_alt, deleted_kf, warm_start, flags)
        return self.checked_altitudes(sol, [m.alt_m for m in edits.moves] if edits else [])

    def _resolve_edit_set(self, edits):
        from posefix.io.edits import EditSet, match_edits

        edits = edits or EditSet()
        matched = match_edits(self.run, edits)
        rows_m = np.asarray(matched.move_index, dtype=np.int64)
        rows_d = np.asarray(matched.deleted_index, dtype=np.int64)
        index = self.keyframes_for(np.concatenate([rows_m, rows_d]))
        edit_kf = np.searchsorted(index, rows_m)
        deleted_kf = np.searchsorted(index, rows_d)
        # one pass over the moves: (lon, lat, alt or NaN) per move
        lla = np.array([(m.lon_deg, m.lat_deg, np.nan if m.alt_m is None else m.alt_m) for m in edits.moves],
                       dtype=float).reshape(-1, 3)
        has_alt = np.array([m.alt_m is not None for m in edits.moves], dtype=bool)
        c_m = self.targets(lla[:, 0], lla[:, 1], lla[:, 2], rows_m)
        return index, edit_kf, c_m, has_alt, deleted_kf

    def _check_rules(self, index, edit_kf, c_m, deleted_kf) -> list[Refusal]:
        rules: EditRules = self.cfg.rules
        moves = [KeyframeMove(int(i), float(c[0]), float(c[1])) for i, c in zip(edit_kf, c_m)]
        check = check_edits(rules, self.p_enu_m[index, :2], moves, [int(d) for d in deleted_kf])
        if check.refusals:
            raise EditRefusedError(check.refusals)
        return check.flags


    def solve_edits(self, edits: Edits, warm_start: Solution | None = None, *, local: bool = False,
                    drift: DriftEstimate | None = None) -> Solution:
        """Solve an edit set on the default keyframes (the server's edits); ``local`` (with a warm
        start) re-optimises only around what changed; ``drift`` replaces the drift estimate."""
        args = (self.keyframe_index, edits.index, targets_enu(self, edits.moves), edits.has_alt,
                np.array(edits.deleted, dtype=np.int64), warm_start, list(edits.flags))
        if local or drift is not None:
            sol = self.solve_rows(*args, local=local, drift=drift, edit_sigma_m=edits.sigma_m)
        else:
            sol = solve_calibrated(self, *args, edit_sigma_m=edits.sigma_m)
        return self.checked_altitudes(sol, [m.alt_m for m in edits.moves])

    def checked_altitudes(self, sol: Solution, edit_alt_m) -> Solution:
        """``sol``, or ``EditRefusedError`` (``altitude_out_of_range``) when a corrected keyframe's
        altitude leaves what the input and the edits' altitudes (None: a 2-D move) allow."""
        alts = np.array([a for a in edit_alt_m if a is not None], dtype=float)
        band = altitude_band(self.run, alts, self.cfg)
        refusal = altitude_refusal(self.lonlatalt(sol)[2], band, sol.active)
        if refusal is not None:
            raise EditRefusedError([refusal])
        return sol

    def preview(self, moves: list[Edit], deleted=(), base_edits: Edits | None = None,
                base: Solution | None = None, warm_start=None) -> Preview:
        """Keyframe-level answer for a live drag of ``moves`` on a base edit set (``engine.preview``).

        ``base`` is the base edit set's exact solution (solved here when not given: a server
        keeps it per revision); ``warm_start`` the previous frame of the same drag (or a function of
        the merged edit set returning it).
        """
        from posefix.engine.preview import preview_batch

        base_edits = base_edits or Edits()
        if base is None:
            base = self.solve_edits(base_edits)
        return preview_batch(self, list(moves), list(deleted), base_edits, base, warm_start)

    def lonlatalt(self, sol: Solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Longitude, latitude (degrees) and altitude (m) of a solution's keyframes, (k,) each."""
        lat, lon, alt = self.geodetic(sol.keyframes.p_enu_m, sol.keyframes.index)
        return np.asarray(lon), np.asarray(lat), np.asarray(alt)

    # ----------------------------------------------------------------- full rate

    def full_run(self, sol: Solution) -> Correction:
        """Propagate a keyframe solution to every sample; drop or flag deleted keyframes' rows."""
        started = time.perf_counter()
        kfs = sol.keyframes
        n = self.run.n
        act = kfs.index[sol.active]
        c_kf = rot.quat_multiply(kfs.q_wxyz[sol.active], rot.quat_conjugate(kfs.reported_q_wxyz[sol.active]))
        p_new, seg, alpha = propagate_corrections(
            self.run.t_s, self.p_enu_m, act, kfs.p_enu_m[sol.active], c_kf,
            self.cfg.propagation.mode, self.along_m,
        )
        # the correction is a rotation of the anchored frame; each sample's quaternion is
        # relative to ENU at its own position, so express each keyframe's correction in its
        # own ENU (neighbouring keyframes' frames differ by micro-radians) and interpolate those
        r = self.local_to_anchor(act)
        c_local = rot.quat_multiply(rot.quat_conjugate(r), rot.quat_multiply(c_kf, r))
        q_new = interpolate_rotations(c_local, seg, alpha, then_multiply_wxyz=self._q_local, kf_index=act)
        lat, lon, alt = self.geodetic(p_new, np.arange(n))
        out = self.run.with_poses(lat, lon, alt, q_new)
        deleted_rows = rows_of_keyframes(kfs.index, n, np.flatnonzero(kfs.deleted))
        if self.cfg.rules.deleted == "remove" and len(deleted_rows):
            keep = np.ones(n, dtype=bool)
            keep[deleted_rows] = False
            kept = np.flatnonzero(keep)
            out = out.take(kept)
        else:
            kept = np.arange(n)
            if len(deleted_rows):
                flagged = np.zeros(n, dtype=np.int8)
                flagged[deleted_rows] = 1
                out = dataclasses.replace(out, extra={**out.extra, "flagged": flagged})
        return Correction(
            run=out, keyframes=kfs, solver=sol.solver, drift=sol.drift, kept_rows=kept, flags=sol.flags,
            propagation_time_s=time.perf_counter() - started, x=sol.x, active=sol.active, terms=sol.terms,
            linearisation=sol.linearisation,
        )


def _same_rows(sol: Solution, act_rows: np.ndarray) -> bool:
    """Whether a solution was solved on these (active) keyframe rows."""
    if sol.keyframes.index is act_rows and bool(sol.active.all()):  # the default keyframes, none removed
        return True
    return bool(np.array_equal(sol.keyframes.index[sol.active], act_rows))


def prepare(run: PoseRun, cfg: CorrectionConfig | None = None) -> Problem:
    """Prepare a run for correction (local frame, keyframes); reusable across edit batches."""
    return Problem(run, cfg)


def correct(run: PoseRun, edits=None, cfg: CorrectionConfig | None = None, warm_start=None) -> Correction:
    """Correct a run with an ``EditSet``: optimise keyframes, propagate to every sample."""
    problem = prepare(run, cfg)
    return problem.full_run(problem.solve(edits, warm_start=warm_start))
