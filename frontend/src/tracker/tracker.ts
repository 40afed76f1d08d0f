/**
 * The online CRF tracker of `posefix.mapmatch.tracker.Tracker`, step for step:
 *
 *   P_t = P_{t−1} + s_t,  q_t = round(P_t/c)·c − round(P_{t−1}/c)·c          (error-diffused increment; round half to even)
 *   r_k = o_k − q_t along/across the step heading θ_t, l_t = |s_t|
 *   f1(k) = −½ (r_along²/σ_l² + r_across²/σ_⊥²),  σ_⊥ = max(l_t·σ_θ, σ_l)
 *   f2(k) = f1 for s_t rotated by e_t, the heading error of the last w steps of the Viterbi path:
 *           e_t = ∠(p(y_t) − p(y_{t−w})) − ∠(P_t − P_{t−w})   (kept when the span < min_span)
 *   trans_t(k) = w1·f1 + w2·f2
 *   f3(v) = −½ (p_v − μ)ᵀ Σ⁻¹ (p_v − μ) for a WiFi fix (μ, Σ), or with the fix's outlier rate ε
 *           log((1 − ε)·c²·N(p_v; μ, Σ) + ε/V);  f4 the Gaussian for a peak (a, σ² I)
 *   state_t = w3·share·f3 + w4·share·f4,  share = (1 − ρ)/(1 + ρ), ρ = e^{−Δt/τ}  (Δt since the last of its kind)
 *
 * fed to the Viterbi filter (its path gives e_t) and the forward filter (its marginal is the
 * live position: mean and 2σ ellipse). The start is a Gaussian (σ = 1 m, cut at 3σ) around
 * a known point, a WiFi fix's Gaussian, or uniform. Each step's posterior also gives its
 * modes and the converged flag (./modes.ts, the definition of posefix.mapmatch.modes).
 */
import { ForwardFilter, type Summary, ViterbiFilter, gaussianSummary, stepFilters } from "./filters";
import { type FingerprintMap, type WifiFix, predictScan, scanPeaks } from "./fingerprints";
import type { TrackerModel } from "./model";
import { type Modes, posteriorModes } from "./modes";
import { type Walk, roundHalfEven, stepVector, stepsFromWalk, wifiScans, wrapAngle } from "./sensors";

export interface Peak {
  xy: [number, number];
  sigma_m: number;
}

export interface TrackPoint {
  t_ms: number;
  summary: Summary;
  vertex: number;
}

export interface TrackerOptions {
  start?: [number, number] | null;
  t0_ms?: number;
  startSigma_m?: number;
  startWifi?: WifiFix | null;
  startWifiT_ms?: number | null;
  wifiCorr_s?: number | null;
  /** Walk-long correlation ρ of WiFi errors (the fingerprint map's walkCorr); 0: the AR(1) discount alone. */
  wifiWalkCorr?: number;
}

/** ρ-discounted share of an observation's evidence (1 for the first, or with τ = 0). */
export function evidenceShare(dt_s: number | null, tau_s: number): number {
  if (dt_s === null || tau_s <= 0) return 1;
  const rho = Math.exp(-Math.abs(dt_s) / tau_s);
  return (1 - rho) / (1 + rho);
}

/** Information (in independent observations) of n whose errors any two share ρ: n / (1 + (n − 1)ρ), n below 1 (features.capped_information). */
export function cappedInformation(n: number, rho: number): number {
  if (rho <= 0 || n <= 1) return n;
  return n / (1 + (n - 1) * rho);
}

/** f3/f4 at every vertex: −½ (p − μ)ᵀ Σ⁻¹ (p − μ). */
export function gaussianPosition(px: Float64Array, py: Float64Array, mean: readonly [number, number], cov: readonly number[], scale = 1, out?: Float64Array): Float64Array {
  const det = cov[0] * cov[3] - cov[1] * cov[2];
  const i00 = cov[3] / det;
  const i11 = cov[0] / det;
  const i01 = -cov[1] / det - cov[2] / det;
  const o = out ?? new Float64Array(px.length);
  for (let v = 0; v < px.length; v++) {
    const dx = px[v] - mean[0];
    const dy = py[v] - mean[1];
    o[v] += scale * (-0.5 * (i00 * dx * dx + i01 * dx * dy + i11 * dy * dy));
  }
  return o;
}

/** f3 at every vertex for a fix: the Gaussian, or with ε > 0 its heavy-tailed form
 * log((1 − ε)·c²·N(p; μ, Σ) + ε/V) (Python's f_robust_position), times `scale`, added to `out`. */
export function wifiPosition(px: Float64Array, py: Float64Array, fix: WifiFix, cell_m: number, scale = 1, out?: Float64Array): Float64Array {
  const eps = fix.eps ?? 0;
  const o = out ?? new Float64Array(px.length);
  if (!(eps > 0)) return gaussianPosition(px, py, fix.mean, fix.cov, scale, o);
  const g = gaussianPosition(px, py, fix.mean, fix.cov, 1);
  const c = fix.cov;
  const logNorm = Math.log((cell_m * cell_m) / (2 * Math.PI * Math.sqrt(c[0] * c[3] - c[1] * c[2])));
  const a = Math.log1p(-eps);
  const b = Math.log(eps / px.length);
  for (let v = 0; v < px.length; v++) {
    const x = a + g[v] + logNorm;
    const hi = Math.max(x, b);
    o[v] += scale * (hi + Math.log1p(Math.exp(Math.min(x, b) - hi)));
  }
  return o;
}

function fStep(m: TrackerModel, sx: number, sy: number, ix: number, iy: number, out: Float64Array, w: number): void {
  const g = m.graph;
  const sg = m.sigmas;
  const l = Math.sqrt(sx * sx + sy * sy);
  const th = Math.atan2(sy, sx);
  const c = Math.cos(th);
  const s = Math.sin(th);
  const sc = Math.max(l * sg.heading_rad, sg.len_m);
  for (let k = 0; k < g.k; k++) {
    const rx = g.offX[k] - ix;
    const ry = g.offY[k] - iy;
    const ra = rx * c + ry * s;
    const rc = -rx * s + ry * c;
    const ta = ra / sg.len_m;
    const tc = rc / sc;
    out[k] += w * (-0.5 * (ta * ta + tc * tc));
  }
}

export function startLogPrior(m: TrackerModel, start: [number, number] | null, sigma = 1): Float64Array {
  const g = m.graph;
  const lp = new Float64Array(g.n);
  if (!start) return lp;
  let dmin = Infinity;
  const d2 = new Float64Array(g.n);
  for (let v = 0; v < g.n; v++) {
    const dx = g.px[v] - start[0];
    const dy = g.py[v] - start[1];
    d2[v] = dx * dx + dy * dy;
    if (d2[v] < dmin) dmin = d2[v];
  }
  const cut = Math.max(9 * sigma * sigma, dmin + 1e-9);
  for (let v = 0; v < g.n; v++) lp[v] = d2[v] <= cut ? (-0.5 * d2[v]) / (sigma * sigma) : -Infinity;
  return lp;
}

export class Tracker {
  readonly viterbi: ViterbiFilter;
  readonly forward: ForwardFilter;
  readonly tau_s: number;
  private lastObs: { f3: number | null; f4: number | null } = { f3: null, f4: null };
  private nEff: { f3: number; f4: number } = { f3: 0, f4: 0 };
  readonly walkCorr: number;
  private cum: [number, number] = [0, 0];
  private cum2: [number, number] = [0, 0];
  private cumHist: [number, number][] = [[0, 0]];
  private lastErr: number | null = null;
  private readonly minSigma: number;
  nSteps = 0;

  constructor(
    readonly model: TrackerModel,
    opts: TrackerOptions = {},
  ) {
    const tau = opts.wifiCorr_s ?? model.sigmas.wifi_corr_s;
    if (!(Number.isFinite(tau) && tau >= 0)) throw new Error(`wifi_corr_s must be a number of seconds >= 0, got ${tau}`);
    this.tau_s = tau;
    this.walkCorr = opts.wifiWalkCorr ?? 0;
    if (!(Number.isFinite(this.walkCorr) && this.walkCorr >= 0 && this.walkCorr < 1)) throw new Error(`wifiWalkCorr must be in [0, 1), got ${this.walkCorr}`);
    const start = opts.start ?? null;
    let prior = startLogPrior(model, start, opts.startSigma_m ?? 1);
    if (!start && opts.startWifi) {
      prior = wifiPosition(model.graph.px, model.graph.py, opts.startWifi, model.graph.cell_m);
      this.lastObs.f3 = Math.trunc(opts.startWifiT_ms ?? opts.t0_ms ?? 0);
      this.nEff.f3 = 1;
    }
    this.viterbi = new ViterbiFilter(model.graph, prior, model.beam, Math.max(model.sigmas.window_steps, 1));
    this.forward = new ForwardFilter(model.graph, prior, model.beam);
    this.minSigma = model.graph.cell_m / Math.sqrt(12);
  }

  private increment(cum: [number, number], sx: number, sy: number): [number, number] {
    const c = this.model.graph.cell_m;
    const nx = cum[0] + sx;
    const ny = cum[1] + sy;
    const ix = roundHalfEven(nx / c) * c - roundHalfEven(cum[0] / c) * c;
    const iy = roundHalfEven(ny / c) * c - roundHalfEven(cum[1] / c) * c;
    cum[0] = nx;
    cum[1] = ny;
    return [ix, iy];
  }

  /** Heading error of the Viterbi path over the last w steps (rad), the rotation f2 applies. */
  headingError(): number {
    const s = this.model.sigmas;
    const n = this.nSteps;
    const a = Math.max(0, n - s.window_steps);
    if (n - a < 2) return this.lastErr ?? 0;
    const dx = this.cumHist[n][0] - this.cumHist[a][0];
    const dy = this.cumHist[n][1] - this.cumHist[a][1];
    const path = this.viterbi.bestPath(n - a);
    const g = this.model.graph;
    const px = g.px[path[path.length - 1]] - g.px[path[0]];
    const py = g.py[path[path.length - 1]] - g.py[path[0]];
    let err = this.lastErr ?? 0;
    if (Math.sqrt(dx * dx + dy * dy) >= s.min_span_m && Math.sqrt(px * px + py * py) > 0) {
      const e = Math.atan2(py, px) - Math.atan2(dy, dx);
      err = wrapAngle(e);
    }
    this.lastErr = err;
    return err;
  }

  transitionScores(sx: number, sy: number): Float64Array {
    const m = this.model;
    const out = new Float64Array(m.graph.k);
    const [ix, iy] = this.increment(this.cum, sx, sy);
    fStep(m, sx, sy, ix, iy, out, m.weights.f1);
    if (m.weights.f2 !== 0) {
      const e = this.headingError();
      const c = Math.cos(e);
      const s = Math.sin(e);
      const rx = c * sx - s * sy;
      const ry = s * sx + c * sy;
      const [jx, jy] = this.increment(this.cum2, rx, ry);
      fStep(m, rx, ry, jx, jy, out, m.weights.f2);
    }
    return out;
  }

  private share(kind: "f3" | "f4", t_ms: number): number {
    const last = this.lastObs[kind];
    const s = evidenceShare(last === null ? null : (Math.trunc(t_ms) - last) / 1000, this.tau_s);
    this.lastObs[kind] = Math.trunc(t_ms);
    const n0 = this.nEff[kind];
    this.nEff[kind] = n0 + s;
    return this.walkCorr > 0 ? cappedInformation(n0 + s, this.walkCorr) - cappedInformation(n0, this.walkCorr) : s;
  }

  stateScores(wifi: WifiFix | null, wifiT: number, peak: Peak | null, peakT: number): Float64Array | null {
    const m = this.model;
    const g = m.graph;
    let out: Float64Array | null = null;
    if (wifi && m.weights.f3 !== 0) {
      out = wifiPosition(g.px, g.py, wifi, g.cell_m, m.weights.f3 * this.share("f3", wifiT));
    }
    if (peak && m.weights.f4 !== 0) {
      const v = peak.sigma_m * peak.sigma_m;
      out = gaussianPosition(g.px, g.py, peak.xy, [v, 0, 0, v], m.weights.f4 * this.share("f4", peakT), out ?? undefined);
    }
    return out;
  }

  /** One detected step (floor-frame vector, m, bias applied) with optional WiFi fix and peak. */
  step(sx: number, sy: number, t_ms: number, wifi: WifiFix | null = null, peak: Peak | null = null, wifiT_ms?: number, peakT_ms?: number): TrackPoint {
    const trans = this.transitionScores(sx, sy);
    const state = this.stateScores(wifi, wifiT_ms ?? t_ms, peak, peakT_ms ?? t_ms);
    stepFilters(this.viterbi, this.forward, trans, state);
    this.nSteps++;
    const last = this.cumHist[this.cumHist.length - 1];
    this.cumHist.push([last[0] + sx, last[1] + sy]);
    return { t_ms, summary: this.summary(), vertex: this.viterbi.top };
  }

  /** Gaussian summary of the live (filtered) distribution. */
  summary(): Summary {
    return gaussianSummary(this.model.graph, this.forward.lin, this.forward.live, this.minSigma, 20, this.model.ellipseScale);
  }

  /** The live distribution's modes and whether it has converged (posefix.mapmatch.modes). */
  modes(): Modes {
    const g = this.model.graph;
    return posteriorModes(g.px, g.py, this.forward.lin, this.forward.live);
  }
}

export interface WalkRun {
  t_ms: Float64Array;
  x: Float64Array;
  y: Float64Array;
  sigma_major_m: Float64Array;
  sigma_minor_m: Float64Array;
  angle_deg: Float64Array;
  dr_x: Float64Array;
  dr_y: Float64Array;
  /** Each row's modes (how many places, how far apart, converged). */
  modes: Modes[];
  /** Time of the loop per step: the filters, the summary and the modes, as a live step. */
  ms_per_step: number;
  tracker: Tracker;
}

/** The online pass of `track_walk` over a parsed walk: the live position after each step. */
export function trackWalk(model: TrackerModel, walk: Walk, start: [number, number] | null, fp: FingerprintMap | null = null, now: () => number = () => performance.now()): WalkRun {
  const steps = stepsFromWalk(walk);
  const n = steps.t_ms.length;
  const t0 = Math.trunc(walk.acc.t[0]);
  const nearest = (t: number) => {
    let best = 0;
    for (let i = 1; i < n; i++) if (Math.abs(steps.t_ms[i] - t) < Math.abs(steps.t_ms[best] - t)) best = i;
    return best;
  };
  const wifiAt = new Map<number, [WifiFix, number]>();
  const peakAt = new Map<number, [Peak, number]>();
  let startWifi: WifiFix | null = null;
  let startWifiT: number | null = null;
  if (fp && n) {
    const scans = wifiScans(walk.wifi);
    for (const s of fp.f3Calibrated ? scans : []) {  // an uncalibrated f3 is left out, as in Python
      const fix = predictScan(fp, s.rssi);
      if (!fix) continue;
      if (!start && !startWifi && !wifiAt.size && s.t_ms <= steps.t_ms[0]) {
        startWifi = fix;
        startWifiT = s.t_ms;
        continue;
      }
      wifiAt.set(nearest(s.t_ms), [fix, s.t_ms]);
    }
    if (fp.peakSigma !== null) {
      for (const pk of scanPeaks(fp, scans)) peakAt.set(nearest(pk.t_ms), [{ xy: fp.peakXY.get(pk.bssid)!, sigma_m: fp.peakSigma }, pk.t_ms]);
    }
  }
  const tr = new Tracker(model, { start, t0_ms: t0, startWifi, startWifiT_ms: startWifiT, wifiWalkCorr: fp?.walkCorr ?? 0 });
  const out: WalkRun = {
    t_ms: new Float64Array(n + 1), x: new Float64Array(n + 1), y: new Float64Array(n + 1),
    sigma_major_m: new Float64Array(n + 1), sigma_minor_m: new Float64Array(n + 1), angle_deg: new Float64Array(n + 1),
    dr_x: new Float64Array(n + 1), dr_y: new Float64Array(n + 1), modes: [tr.modes()], ms_per_step: 0, tracker: tr,
  };
  const put = (i: number, t: number, s: Summary) => {
    out.t_ms[i] = t;
    out.x[i] = s.x;
    out.y[i] = s.y;
    out.sigma_major_m[i] = s.sigma_major_m;
    out.sigma_minor_m[i] = s.sigma_minor_m;
    out.angle_deg[i] = s.angle_deg;
  };
  put(0, t0, tr.summary());
  out.dr_x[0] = start ? start[0] : 0;
  out.dr_y[0] = start ? start[1] : 0;
  const tic = now();
  for (let i = 0; i < n; i++) {
    const [sx, sy] = stepVector(model.step, steps.freq_hz[i], steps.heading_rad[i]);
    const w = wifiAt.get(i);
    const pk = peakAt.get(i);
    const tp = tr.step(sx, sy, steps.t_ms[i], w?.[0] ?? null, pk?.[0] ?? null, w?.[1], pk?.[1]);
    put(i + 1, steps.t_ms[i], tp.summary);
    out.modes.push(tr.modes());
    out.dr_x[i + 1] = out.dr_x[i] + sx;
    out.dr_y[i + 1] = out.dr_y[i] + sy;
  }
  out.ms_per_step = (now() - tic) / Math.max(n, 1);
  return out;
}
