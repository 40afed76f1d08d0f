"""Tracking: steps (+ WiFi) -> matched positions with uncertainty, online or for a whole walk.

:class:`Tracker` is the online engine (one call per step, as a phone or a REST session
would feed it). :func:`track_walk` runs it over a parsed walk, back-tracks the most
likely path at the end (offline Viterbi), and by default reports each step's smoothed
posterior mean (forward-backward over the same scores): the minimum mean-squared-error
estimate, which on the shared walks beats the Viterbi vertices (1.6 vs 1.8 m mean).

f2 is computed online: before step t, the heading error over the last w steps of the
current most likely path (:func:`posefix.mapmatch.features.heading_errors_from_path`)
rotates the step (the patent's "estimate heading from the confident path and correct the
heading bias"). The patent's other optimisation, replacing a confident column by its
Gaussian, is ``collapse_sigma_m``: when the column's major 1σ is below it, the column is
replaced by the log-density of its Gaussian on the vertices within 3σ, which bounds the
active set. It is off (0) by default because the beam already keeps steps fast here.

WiFi evidence is discounted for its correlation in time: each f3 (WiFi position) and f4
(RSSI peak) score is multiplied by the share of new information it carries given the
previous observation of its kind, ``(1 - ρ)/(1 + ρ)`` with ``ρ = e^{-Δt/τ}``
(:func:`posefix.mapmatch.features.evidence_share`; τ = ``model.sigmas.wifi_corr_s``, 20 s,
0 = scans independent). The tracker keeps the last observation times, so the live filter,
the Viterbi path and the offline smoothing (which reuses the weighted scores) all see the
same discounted evidence.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from posefix.mapmatch.features import (FeatureSigmas, capped_information, evidence_share, f_gaussian_position,
                                       f_robust_position, f_step)
from posefix.mapmatch.modes import CONVERGED_MASS, CONVERGED_SIGMA_M, Modes, posterior_modes
from posefix.mapmatch.viterbi import ForwardFilter, GaussianSummary, ViterbiFilter, forward_backward, gaussian_summary

__all__ = ["TrackPoint", "Tracker", "TrackResult", "track_walk", "smooth", "start_log_prior"]


def start_log_prior(p_xy_m: np.ndarray, start_xy_m: tuple[float, float] | None,
                    sigma_m: float = 1.0) -> np.ndarray:
    """Log prior (V,) over vertices: Gaussian (σ = ``sigma_m``, cut at 3σ but never empty)
    around a known start, or uniform over all reachable vertices when ``start_xy_m`` is None."""
    if start_xy_m is None:
        return np.zeros(p_xy_m.shape[0])
    d2 = np.sum((p_xy_m - np.asarray(start_xy_m, dtype=float)) ** 2, axis=1)
    lp = -0.5 * d2 / sigma_m**2
    cut = max(9.0 * sigma_m**2, float(np.min(d2)) + 1e-9)
    return np.where(d2 <= cut, lp, -np.inf)


def wifi_score(p_xy_m: np.ndarray, wifi: tuple, cell_m: float) -> np.ndarray:
    """f3 (V,) for a WiFi observation ``(mean (2,), cov (2, 2))`` or ``(mean, cov, outlier_frac)``:
    the Gaussian, or its robust form when an outlier fraction ε > 0 is given
    (:func:`posefix.mapmatch.features.f_robust_position`)."""
    if len(wifi) > 2 and wifi[2] > 0.0:
        return f_robust_position(p_xy_m, wifi[0], wifi[1], float(wifi[2]), cell_m)
    return f_gaussian_position(p_xy_m, wifi[0], wifi[1])


@dataclass(frozen=True)
class TrackPoint:
    """One step's output: filtered (online) position and its Gaussian summary (None when not asked)."""

    t_ms: int
    vertex: int
    summary: GaussianSummary | None


@dataclass(frozen=True)
class TrackResult:
    """A tracked walk: ``t_ms`` (T+1,), ``p_xy_m`` (T+1, 2) of the offline most likely path,
    ``sigma_major_m``/``sigma_minor_m``/``angle_deg`` (T+1,) of each step's column, and
    ``dr_xy_m`` (T+1, 2) the plain dead-reckoning track from the same start.
    ``time_per_step_s``: CPU time of the online step; ``offline_time_per_step_s`` with the
    offline back-track and smoothing included. ``modes`` (T+1,): each row's
    :class:`posefix.mapmatch.modes.Modes` (how many places the walker may be, how far
    apart, and whether the posterior has converged on one)."""

    t_ms: np.ndarray
    p_xy_m: np.ndarray
    vertex: np.ndarray
    sigma_major_m: np.ndarray
    sigma_minor_m: np.ndarray
    angle_deg: np.ndarray
    online_xy_m: np.ndarray
    dr_xy_m: np.ndarray
    time_per_step_s: float
    offline_time_per_step_s: float
    modes: tuple = ()
    step_correction: complex = 1.0 + 0j  # the walk's own step scale and heading, |a|·e^{i·arg a} (calibrate.py)

    @property
    def converged(self) -> np.ndarray:
        """(T+1,) bool: the row's posterior has converged on one place (its ellipse is a fix)."""
        return np.array([m.converged for m in self.modes], dtype=bool)

    @property
    def n_modes(self) -> np.ndarray:
        return np.array([m.n for m in self.modes], dtype=np.int64)

    @property
    def mode_spread_m(self) -> np.ndarray:
        return np.array([m.spread_m for m in self.modes])


class Tracker:
    """Online CRF tracker over a :class:`posefix.mapmatch.model.Model`.

    ``start_wifi``: with ``start_xy_m`` None, an optional WiFi prediction ``(mean, cov[, ε])``
    of a scan taken before the first step (at ``start_wifi_t_ms``, default ``t0_ms``): the
    start prior instead of the uniform one, and the first scan of the WiFi discount.

    ``wifi_corr_s``: correlation time τ (s) of WiFi errors for the discount of f3/f4
    (module docstring); None: the model's ``sigmas.wifi_corr_s``; 0: every scan independent.

    ``filtered`` (default): the live distribution (``column()``, each step's summary) is a
    forward (sum-product) filter's marginal; False: the Viterbi max-product column (no
    second filter to run).

    ``step(step_xy_m, t_ms, wifi=None, peak=None)``: one detected step as a floor-frame
    vector (m, heading bias already applied); ``wifi`` an optional ``(mean (2,), cov (2,2)[, ε])``
    position predicted by the fingerprint map, ``peak`` an optional ``(xy (2,), sigma_m)``
    RSSI-peak location; ``wifi_t_ms``/``peak_t_ms``: when they were measured (default the
    step's ``t_ms``), for the discount. Returns a :class:`TrackPoint` (``vertex``: the
    Viterbi column's best).
    """

    def __init__(self, model, start_xy_m: tuple[float, float] | None = None, t0_ms: int = 0,
                 start_sigma_m: float = 1.0, collapse_sigma_m: float = 0.0, start_wifi: tuple | None = None,
                 filtered: bool = True, wifi_corr_s: float | None = None, start_wifi_t_ms: int | None = None,
                 wifi_walk_corr: float = 0.0):
        self.model = model
        g = model.graph
        self.graph = g
        self.p_xy_m = g.p_xy_m
        self.offsets_m = g.offsets_m
        self.w = model.weights
        self.sig: FeatureSigmas = model.sigmas
        self.collapse_sigma_m = collapse_sigma_m
        tau = self.sig.wifi_corr_s if wifi_corr_s is None else float(wifi_corr_s)
        if not (np.isfinite(tau) and tau >= 0.0):
            raise ValueError(f"wifi_corr_s must be a number of seconds >= 0, got {wifi_corr_s}")
        self.wifi_corr_s = tau
        if not (np.isfinite(wifi_walk_corr) and 0.0 <= wifi_walk_corr < 1.0):
            raise ValueError(f"wifi_walk_corr must be in [0, 1), got {wifi_walk_corr}")
        self.wifi_walk_corr = float(wifi_walk_corr)
        self._n_eff: dict[str, float] = {"f3": 0.0, "f4": 0.0}  # AR(1) shares summed so far
        # Time (ms) of the last observation of each WiFi feature, for evidence_share.
        self._last_obs_ms: dict[str, int | None] = {"f3": None, "f4": None}
        self.shares: list[tuple[str, int, float]] = []  # (feature, t_ms, share) as applied
        prior = start_log_prior(self.p_xy_m, start_xy_m, start_sigma_m)
        if start_xy_m is None and start_wifi is not None:
            # Unknown start, but a WiFi scan before the first step: its prediction is the prior
            # (unweighted: a prior is a distribution, not a feature). It is the walk's first
            # scan, so the next one's share is counted from it.
            prior = wifi_score(self.p_xy_m, start_wifi, g.cell_m)
            self._last_obs_ms["f3"] = int(t0_ms if start_wifi_t_ms is None else start_wifi_t_ms)
            self._n_eff["f3"] = 1.0
        self.filter = ViterbiFilter(g, prior, beam=model.beam)
        self.forward = ForwardFilter(g, prior, beam=model.beam) if filtered else None
        c = g.cell_m
        self._c = c
        self._cum = np.zeros(2)  # dead-reckoning sum (f1)
        self._cum2 = np.zeros(2)  # heading-corrected sum (f2)
        self._steps: list[np.ndarray] = []
        self.log_prior = self.filter.delta.copy()
        # The weighted scores the filter saw, kept for offline smoothing (K floats per step;
        # a (V,) vector only at steps with a WiFi or peak observation).
        self.trans_rows: list[np.ndarray] = []
        self.state_rows: list[np.ndarray | None] = []
        self.t_ms: list[int] = [int(t0_ms)]
        self._cum_hist = [np.zeros(2)]
        self._trans_log_norm = 0.0  # Σ_t log Σ_k exp(trans[t, k]), for log_evidence

    def _increment(self, cum: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        new = cum + step
        c = self._c
        return new, np.round(new / c) * c - np.round(cum / c) * c

    def _heading_error(self) -> float:
        s = self.sig
        n = len(self._steps)
        a = max(0, n - s.window_steps)
        if n - a < 2:
            return 0.0 if not hasattr(self, "_last_err") else self._last_err
        dr = self._cum_hist[n] - self._cum_hist[a]
        path = self.filter.best_path(last_n=n - a)
        pp = self.p_xy_m[path[-1]] - self.p_xy_m[path[0]]
        err = getattr(self, "_last_err", 0.0)
        if np.linalg.norm(dr) >= s.min_span_m and np.linalg.norm(pp) > 0:
            e = np.arctan2(pp[1], pp[0]) - np.arctan2(dr[1], dr[0])
            err = float((e + np.pi) % (2 * np.pi) - np.pi)
        self._last_err = err
        return err

    def transition_scores(self, step_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(K,) weighted transition scores for this step, plus its raw f1 and f2 rows."""
        step = np.asarray(step_xy_m, dtype=float)
        self._cum, inc1 = self._increment(self._cum, step)
        f1 = f_step(self.offsets_m, step[None], inc1[None], self.sig)[0]
        w1, w2 = self.w["f1"], self.w["f2"]
        f2 = np.zeros_like(f1)
        if w2 != 0.0:
            e = self._heading_error()
            c, s = np.cos(e), np.sin(e)
            step2 = np.array([c * step[0] - s * step[1], s * step[0] + c * step[1]])
            self._cum2, inc2 = self._increment(self._cum2, step2)
            f2 = f_step(self.offsets_m, step2[None], inc2[None], self.sig)[0]
        return w1 * f1 + w2 * f2, f1, f2

    def evidence_share(self, feature: str, t_ms: int) -> float:
        """Share of a WiFi observation's evidence (f3 or f4) measured at ``t_ms`` that is new
        given the ones before it, and remember its time: its AR(1) share given the previous
        one (1 for the first), then, with ``wifi_walk_corr`` ρ, what it adds to the capped
        information of all of them (:func:`posefix.mapmatch.features.capped_information`)."""
        last = self._last_obs_ms[feature]
        share = evidence_share(None if last is None else (int(t_ms) - last) / 1000.0, self.wifi_corr_s)
        self._last_obs_ms[feature] = int(t_ms)
        n0 = self._n_eff[feature]
        self._n_eff[feature] = n0 + share
        if self.wifi_walk_corr > 0.0:
            share = (capped_information(n0 + share, self.wifi_walk_corr)
                     - capped_information(n0, self.wifi_walk_corr))
        self.shares.append((feature, int(t_ms), share))
        return share

    def state_scores(self, wifi=None, peak=None, wifi_t_ms: int | None = None,
                     peak_t_ms: int | None = None) -> np.ndarray | None:
        """(V,) weighted state scores from a WiFi prediction and/or an RSSI peak, or None; each
        weighted by its feature weight and its share of new evidence (:meth:`evidence_share`,
        which needs the observations' times and advances the discount's clock)."""
        if (wifi is not None and wifi_t_ms is None) or (peak is not None and peak_t_ms is None):
            raise ValueError("state_scores needs the time (ms) each WiFi observation was measured")
        out = None
        if wifi is not None and self.w["f3"] != 0.0:
            share = self.evidence_share("f3", wifi_t_ms)
            out = (self.w["f3"] * share) * wifi_score(self.p_xy_m, wifi, self._c)
        if peak is not None and self.w["f4"] != 0.0:
            share = self.evidence_share("f4", peak_t_ms)
            f4 = (self.w["f4"] * share) * f_gaussian_position(self.p_xy_m, peak[0], np.eye(2) * peak[1] ** 2)
            out = f4 if out is None else out + f4
        return out

    def step(self, step_xy_m: np.ndarray, t_ms: int, wifi=None, peak=None, summarise: bool = True,
             wifi_t_ms: int | None = None, peak_t_ms: int | None = None) -> TrackPoint:
        """One step; ``summarise=False`` skips the column's Gaussian summary (``summary`` None,
        ``vertex`` the best δ) for a caller that reads only some steps (suggestions' sub-steps).
        ``wifi_t_ms``/``peak_t_ms``: when the scan was measured (default ``t_ms``)."""
        trans, _, _ = self.transition_scores(step_xy_m)
        state = self.state_scores(wifi, peak, t_ms if wifi_t_ms is None else wifi_t_ms,
                                  t_ms if peak_t_ms is None else peak_t_ms)
        self.filter.step(trans, state)
        top = float(np.max(trans))
        self._trans_log_norm += top + float(np.log(np.sum(np.exp(trans - top))))
        self.trans_rows.append(trans)
        self.state_rows.append(state)
        self._steps.append(np.asarray(step_xy_m, dtype=float))
        self._cum_hist.append(self._cum_hist[-1] + self._steps[-1])
        self.t_ms.append(int(t_ms))
        if self.forward is not None:
            self.forward.step(trans, state)
        if not summarise and self.collapse_sigma_m <= 0:
            return TrackPoint(t_ms=int(t_ms), vertex=int(np.argmax(self.filter.delta)), summary=None)
        col = self.column()
        summ = self.summary(col)
        if self.collapse_sigma_m > 0 and summ.sigma_major_m < self.collapse_sigma_m:
            g = f_gaussian_position(self.p_xy_m, summ.mean_xy_m, summ.cov_m2)
            self.filter.delta = np.where(np.isfinite(self.filter.delta) & (g > -4.5), g, -np.inf)
            if self.forward is not None:
                self.forward.alpha = np.where(np.isfinite(self.forward.alpha) & (g > -4.5), g, -np.inf)
        return TrackPoint(t_ms=int(t_ms), vertex=int(np.argmax(self.filter.delta)), summary=summ)

    def summary(self, logp: np.ndarray) -> GaussianSummary:
        """Gaussian summary of a distribution over the vertices, with the cell's own spread
        and the model's calibrated ellipse scale (:attr:`Model.ellipse_scale`)."""
        return gaussian_summary(self.p_xy_m, logp, min_sigma_m=self._c / np.sqrt(12.0),
                                cov_scale=getattr(self.model, "ellipse_scale", 1.0))

    def column(self) -> np.ndarray:
        """The live distribution (V,) log p: the forward filter's marginal p(y_t | steps so far),
        or the Viterbi max-product column when the tracker was made with ``filtered=False``."""
        return self.forward.column() if self.forward is not None else self.filter.column()

    def best_path(self) -> np.ndarray:
        """Offline answer so far: the most likely vertex sequence y_0..y_t."""
        return self.filter.best_path()

    def log_evidence(self) -> float:
        """How well the map (and WiFi) explain the steps so far: log Σ over paths of the prior
        times, per step, the move's probability ``exp(trans[k]) / Σ_k' exp(trans[k'])`` (each
        step's scores normalised over all offsets, as on an open floor, so a wall takes
        probability away) times the state scores. Steps that agree with the walls score
        higher; comparable between runs of the same walk and prior with other step vectors
        (:func:`posefix.mapmatch.calibrate.select_step_correction`). Needs ``filtered``."""
        if self.forward is None:
            raise ValueError("log_evidence needs the forward filter (Tracker(filtered=True))")
        return self.forward.log_evidence() - self._trans_log_norm


def smooth(tracker: Tracker, with_modes: bool = False, gamma_out: list | None = None):
    """Offline smoothing of everything a tracker has seen: forward-backward marginals
    p(y_t | all steps) over the same scores, returned as posterior means (T+1, 2) — the
    minimum mean-squared-error positions — and their Gaussian summaries (and, with
    ``with_modes``, each marginal's :class:`posefix.mapmatch.modes.Modes` third).
    ``gamma_out``: a list the marginals (T+1, V) are appended to."""
    g = tracker.graph
    fb = forward_backward(g, tracker.log_prior, np.asarray(tracker.trans_rows).reshape(-1, g.offsets.shape[0]),
                          tracker.state_rows, beam=tracker.model.beam)
    if gamma_out is not None:
        gamma_out.append(fb.gamma)
    sums, modes = [], []
    for row in fb.gamma:
        with np.errstate(divide="ignore"):
            sums.append(tracker.summary(np.log(row)))
        if with_modes:
            modes.append(posterior_modes(tracker.p_xy_m, row))
    means = np.array([s.mean_xy_m for s in sums])
    return (means, sums, modes) if with_modes else (means, sums)


def _walk_observations(model, walk, steps, start_xy_m, fingerprints) -> tuple[dict, dict, tuple | None, int | None, float]:
    """WiFi fixes and RSSI peaks of a walk attached to its steps: ``{step: (observation, t_ms
    measured)}`` each (two nearest the same step: the later is kept), the start prior's
    scan (a scan before the first step, unknown start only) with its time, and the
    fingerprint map's walk-long error correlation (:attr:`FingerprintMap.walk_corr`; 0 without)."""
    wifi_at: dict[int, tuple] = {}
    peak_at: dict[int, tuple] = {}
    start_wifi, start_wifi_t = None, None
    if fingerprints is not None and len(steps):
        eps = fingerprints.outlier_frac if getattr(fingerprints, "robust", False) else 0.0
        for t_ms, mean, cov in fingerprints.predict_walk(walk, model.graph.p_xy_m):
            if start_xy_m is None and start_wifi is None and not wifi_at and t_ms <= steps.t_ms[0]:
                start_wifi, start_wifi_t = (mean, cov, eps), int(t_ms)  # before the first step: the start prior
                continue
            wifi_at[int(np.argmin(np.abs(steps.t_ms - t_ms)))] = ((mean, cov, eps), int(t_ms))
        for t_ms, xy, sig in fingerprints.peaks_in_walk(walk):
            peak_at[int(np.argmin(np.abs(steps.t_ms - t_ms)))] = ((xy, sig), int(t_ms))
    return wifi_at, peak_at, start_wifi, start_wifi_t, float(getattr(fingerprints, "walk_corr", 0.0) or 0.0)


def track_walk(model, walk, start_xy_m: tuple[float, float] | None = None, fingerprints=None,
               heading: str = "rotation_vector", estimate: str = "mean",
               on_step: Callable[[int, int], None] | None = None,
               wifi_corr_s: float | None = None, self_calibrate: bool = True, em_iterations: int = 2,
               heading_only: bool = True, walk_spread: tuple[float, float] | None = None) -> TrackResult:
    """Track a parsed :class:`posefix.mapmatch.sensors.Walk` (its waypoints are not read).

    ``fingerprints``: an optional :class:`posefix.mapmatch.fingerprints.FingerprintMap`
    giving f3 (and f4) observations, each attached to the step nearest in time and
    discounted by the time since the previous one (``wifi_corr_s``: τ in seconds, None =
    the model's, 0 = scans independent; see :class:`Tracker`).
    ``estimate``: ``"mean"`` (default) reports the smoothed posterior mean and its
    ellipse (:func:`smooth`); ``"viterbi"`` the most likely path's vertices with the
    online columns' ellipses. ``vertex`` is the Viterbi path in both cases.
    ``self_calibrate`` (with ``"mean"``): EM inside the walk (:mod:`posefix.mapmatch.calibrate`):
    the walk's own step-length scale and heading offset from its converged stretches,
    ``em_iterations`` re-runs; the result's ``step_correction`` is the a found (1 = none).
    The live positions and the online time are the first pass's (a live session cannot
    know the whole walk).
    ``walk_spread`` (with ``"mean"``): σ of the walk's own heading offset (rad) and step-length
    scale (log), ``(heading_sd_rad, scale_sd)``: the heading's is the EM's prior, and both are
    marginalised about the calibrated walk (:func:`_marginalise_walk`); None = the model's
    (``walk_heading_sd_rad``, ``walk_scale_sd``). With an unknown start the EM prior stays
    :data:`posefix.mapmatch.calibrate.SIGMA_A`, and the marginalisation costs four more whole
    passes over every live vertex offline; it is what keeps a converged ellipse honest there:
    once the place is found the walk's own heading and stride dominate the error. The modes
    and "converged" of each row are then the marginalised posterior's (:func:`walk_modes`).
    """
    import time

    from posefix.mapmatch.calibrate import SIGMA_A, apply_step_correction, estimate_step_correction
    from posefix.mapmatch.sensors import steps_from_walk

    if estimate not in ("mean", "viterbi"):
        raise ValueError(f"estimate must be 'mean' or 'viterbi', got {estimate!r}")
    steps = steps_from_walk(walk, heading=heading)
    vec = steps.vectors_m(model.step_model)
    obs = _walk_observations(model, walk, steps, start_xy_m, fingerprints)
    central_gamma: list = []  # the latest central run's smoothed marginals (for the mixture's modes)
    first = _track_pass(model, walk, steps, vec, obs, start_xy_m, estimate, on_step, wifi_corr_s,
                        gamma_out=central_gamma)
    res, a, extra_s = first, 1.0 + 0j, 0.0
    if walk_spread is None:
        walk_spread = (model.walk_heading_sd_rad, model.walk_scale_sd)
    sd = np.asarray(walk_spread, dtype=float)
    # The offset's prior is the spread it is marginalised with: EM finds the walk's own offset,
    # the quadrature spreads around it. With an unknown start EM keeps its own prior: it reads
    # only the stretches that converged, which the spread does not describe.
    sigma_a = float(sd[0]) if sd[0] > 0.0 and start_xy_m is not None else SIGMA_A
    if self_calibrate and estimate == "mean" and len(steps) >= 8:
        for _ in range(em_iterations):
            a_new = estimate_step_correction(vec, res.p_xy_m, res.converged, model.graph.cell_m, model.sigmas.len_m,
                                             sigma_a=sigma_a)
            if abs(a_new - a) < 0.005:
                break
            a = a_new / abs(a_new) if heading_only else a_new
            del central_gamma[:]
            res = _track_pass(model, walk, steps, apply_step_correction(vec, a), obs, start_xy_m, estimate, None,
                              wifi_corr_s, gamma_out=central_gamma)
            extra_s += res.offline_time_per_step_s
    if estimate == "mean" and np.any(sd > 0.0) and len(steps) >= 2:
        runs = []
        w = WALK_NODES[:, 2] / WALK_NODES[:, 2].sum()
        mix = None  # Σ_h w_h γ_h: the walk-marginalised posterior over places, row by row
        for (dh, dk, _), wh in zip(WALK_NODES, w):
            if dh == 0.0 and dk == 0.0:
                runs.append(res)
                g = central_gamma[-1]
            else:
                turn = a * np.exp(dk * sd[1] + 1j * dh * sd[0])
                node_gamma: list = []
                runs.append(_track_pass(model, walk, steps, apply_step_correction(vec, turn), obs, start_xy_m,
                                        estimate, None, wifi_corr_s, light=True, gamma_out=node_gamma))
                extra_s += runs[-1].offline_time_per_step_s
                g = node_gamma[0]
            if mix is None:
                mix = wh * g
            else:
                mix += wh * g
        tic = time.process_time()
        res = _marginalise_walk(runs, WALK_NODES[:, 2])
        res = replace(res, modes=tuple(walk_modes(model.graph.p_xy_m, row, s)
                                       for row, s in zip(mix, res.sigma_major_m)))
        extra_s += (time.process_time() - tic) / max(len(steps), 1)
    return replace(res, online_xy_m=first.online_xy_m, dr_xy_m=first.dr_xy_m, time_per_step_s=first.time_per_step_s,
                   offline_time_per_step_s=first.offline_time_per_step_s + extra_s, step_correction=a)


# Quadrature of (δ, log k) ~ N(0, diag(σ_δ², σ_k²)) in units of σ: (δ node, k node, weight). The
# centre and ±√3 along each axis: each axis alone is the three-point Gauss-Hermite rule (exact for
# a response up to fifth order), five passes instead of nine for the full product.
WALK_NODES = np.array([[0.0, 0.0, 1.0 / 3.0],
                       [-np.sqrt(3.0), 0.0, 1.0 / 6.0], [np.sqrt(3.0), 0.0, 1.0 / 6.0],
                       [0.0, -np.sqrt(3.0), 1.0 / 6.0], [0.0, np.sqrt(3.0), 1.0 / 6.0]])


def walk_modes(p_xy_m: np.ndarray, prob: np.ndarray, sigma_major_m: float) -> Modes:
    """Modes of a walk-marginalised marginal ``prob`` (V,) (the mixture over the quadrature
    nodes of the walk's heading offset and stride), judged on what is reported: rule (1) of
    :mod:`posefix.mapmatch.modes` on the mixture (a place that only the calibrated heading
    finds is not one place), rule (2) on the reported ellipse's 1σ major semi-axis
    ``sigma_major_m`` (the mixture's spread about the reported position)."""
    m = posterior_modes(p_xy_m, prob)
    return replace(m, sigma_major_m=float(sigma_major_m),
                   converged=bool(m.mass[0] >= CONVERGED_MASS and sigma_major_m <= CONVERGED_SIGMA_M))


def _row_covariances(res: TrackResult) -> np.ndarray:
    """(T+1, 2, 2) covariances rebuilt from a result's 1σ semi-axes and angles."""
    a = np.radians(res.angle_deg)
    u = np.stack([np.cos(a), np.sin(a)], axis=1)
    v = np.stack([-np.sin(a), np.cos(a)], axis=1)
    return (res.sigma_major_m**2)[:, None, None] * u[:, :, None] * u[:, None, :] + \
        (res.sigma_minor_m**2)[:, None, None] * v[:, :, None] * v[:, None, :]


def _marginalise_walk(runs: list[TrackResult], weights: np.ndarray) -> TrackResult:
    """The walk's own heading offset and step scale marginalised: ``runs`` are the same walk
    smoothed with its steps turned and scaled at each quadrature node of their distribution,
    ``weights`` the nodes' weights; the first of the largest weight is the central run (the
    walk as calibrated). Each row keeps the central run's position μ_c and reports the mixture's
    mean squared error about it,

        Σ = Σ_h w_h (Σ_h + (μ_h - μ_c)(μ_h - μ_c)ᵀ),

    so the ellipse holds the spread that an offset or a stride lasting the whole walk causes,
    which a CRF with per-step independent errors cannot see. The position is not the mixture's
    mean: a turned or stretched walk that ends in the wrong corridor would drag it. The weights
    are the prior's, not the walk's evidence: the evidence counts every step's error as
    independent too, so it picks one offset far more confidently than it should. Vertex path,
    modes and converged are the central run's (:func:`track_walk` replaces the modes with
    :func:`walk_modes` of the mixture of the runs' marginals)."""
    w = np.asarray(weights, dtype=float) / np.sum(weights)
    centre = runs[int(np.argmax(w))]
    mu = centre.p_xy_m
    cov = sum(wi * (_row_covariances(r) + np.einsum("ti,tj->tij", r.p_xy_m - mu, r.p_xy_m - mu))
              for wi, r in zip(w, runs))
    evals, evecs = np.linalg.eigh(cov)
    major = evecs[:, :, 1]
    return replace(centre, p_xy_m=mu, sigma_major_m=np.sqrt(np.maximum(evals[:, 1], 0.0)),
                   sigma_minor_m=np.sqrt(np.maximum(evals[:, 0], 0.0)),
                   angle_deg=np.degrees(np.arctan2(major[:, 1], major[:, 0])) % 180.0)


def walk_log_evidence(model, walk, steps, vec, obs, start_xy_m, wifi_corr_s=None) -> float:
    """:meth:`Tracker.log_evidence` of a whole walk tracked with step vectors ``vec`` (T, 2):
    one forward pass without summaries (``obs`` from :func:`_walk_observations`)."""
    wifi_at, peak_at, start_wifi, start_wifi_t, walk_corr = obs
    tr = Tracker(model, start_xy_m=start_xy_m, t0_ms=int(walk.acc[0, 0]), start_wifi=start_wifi,
                 wifi_corr_s=wifi_corr_s, start_wifi_t_ms=start_wifi_t, wifi_walk_corr=walk_corr)
    for i in range(len(steps)):
        wifi, wifi_t = wifi_at.get(i, (None, None))
        peak, peak_t = peak_at.get(i, (None, None))
        tr.step(vec[i], int(steps.t_ms[i]), wifi=wifi, peak=peak, summarise=False, wifi_t_ms=wifi_t, peak_t_ms=peak_t)
    return tr.log_evidence()


def _track_pass(model, walk, steps, vec, obs, start_xy_m, estimate, on_step, wifi_corr_s,
                light: bool = False, gamma_out: list | None = None) -> TrackResult:
    """One run of the tracker over a walk's step vectors ``vec`` (see :func:`track_walk`).
    ``light`` (a quadrature node of :func:`_marginalise_walk`, which reads only the smoothed
    positions and ellipses): no live filter, no per-step summaries, no modes (``modes`` empty,
    ``online_xy_m`` the dead reckoning). ``gamma_out``: a list the smoothed marginals are
    appended to (``"mean"`` only)."""
    import time

    wifi_at, peak_at, start_wifi, start_wifi_t, walk_corr = obs
    t0 = int(walk.acc[0, 0])
    tr = Tracker(model, start_xy_m=start_xy_m, t0_ms=t0, start_wifi=start_wifi, wifi_corr_s=wifi_corr_s,
                 start_wifi_t_ms=start_wifi_t, wifi_walk_corr=walk_corr, filtered=not light)
    pts = [tr.summary(tr.column())]
    online = [pts[0].mean_xy_m]
    cols = [np.exp(tr.column())] if estimate == "viterbi" else None
    tic = time.process_time()  # CPU time of this process: "one core", whatever else runs
    for i in range(len(steps)):
        wifi, wifi_t = wifi_at.get(i, (None, None))
        peak, peak_t = peak_at.get(i, (None, None))
        tp = tr.step(vec[i], int(steps.t_ms[i]), wifi=wifi, peak=peak, wifi_t_ms=wifi_t, peak_t_ms=peak_t,
                     summarise=not light)
        if light:
            continue
        pts.append(tp.summary)
        online.append(tp.summary.mean_xy_m)
        if cols is not None:
            cols.append(np.exp(tr.column()))
        if on_step is not None:
            on_step(i + 1, len(steps))
    path = tr.best_path()
    online_s = time.process_time() - tic
    p_out = tr.p_xy_m[path]
    modes: list = []
    if estimate == "mean" and len(steps):
        if light:
            p_out, pts = smooth(tr, gamma_out=gamma_out)
        else:
            p_out, pts, modes = smooth(tr, with_modes=True, gamma_out=gamma_out)
    if cols is not None or not len(steps):
        modes = [posterior_modes(tr.p_xy_m, c) for c in (cols or [np.exp(tr.column())])]
    total_s = time.process_time() - tic
    start = np.zeros(2) if start_xy_m is None else np.asarray(start_xy_m, dtype=float)
    dr = start + np.vstack([np.zeros((1, 2)), np.cumsum(vec, axis=0)])
    if light:
        online = dr
    n = max(len(steps), 1)
    return TrackResult(
        t_ms=np.asarray(tr.t_ms, dtype=np.int64),
        p_xy_m=p_out,
        vertex=path,
        sigma_major_m=np.array([p.sigma_major_m for p in pts]),
        sigma_minor_m=np.array([p.sigma_minor_m for p in pts]),
        angle_deg=np.array([p.angle_deg for p in pts]),
        online_xy_m=np.asarray(online),
        dr_xy_m=dr,
        time_per_step_s=online_s / n,
        offline_time_per_step_s=total_s / n,
        modes=tuple(modes),
    )
