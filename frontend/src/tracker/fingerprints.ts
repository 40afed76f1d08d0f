/**
 * WiFi fingerprint map (f3) and access-point RSSI peaks (f4) from the fingerprint file
 * `posefix.mapmatch.fingerprints` writes, predicted as it does:
 *
 *   d_i  = sqrt(mean_{a heard by the scan} (R_ia − r_a)²)      (float32, −100 dBm = not heard)
 *   w_i  = 1 / (d_i + 1 dB) over the k = 5 nearest, normalised
 *   μ    = Σ w_i p_i,   Σ = s(d_min)·(Σ w_i (p_i − μ)(p_i − μ)ᵀ + (2 m)² I)
 *
 * with s(d_min) the calibrated scale interpolated in the best match's distance (or one
 * scale). With `f3_robust` the fix carries the survey's outlier rate ε (`outlier_frac`) and
 * f3 is the heavy-tailed log((1 − ε)·c²·N(p; μ, Σ) + ε/V), as in Python. A peak: a known access point reading ≥ −55 dBm and more than in the scans just
 * before and after, the strongest one a scan; its observation is (its surveyed peak
 * location, the calibrated σ), none when σ was not calibrated.
 */
import { type NpyArray, NpzFormatError, readNpz } from "./npz";
import type { Scan } from "./sensors";

export const MISSING_DBM = -100;

export interface WifiFix {
  mean: [number, number];
  cov: [number, number, number, number]; // row-major 2x2
  /** Outlier rate ε of f3's heavy-tailed form (0: the plain Gaussian). */
  eps?: number;
}

export interface FingerprintMap {
  bssids: string[];
  col: Map<string, number>;
  px: Float64Array;
  py: Float64Array;
  rssi: Float32Array; // (N, A) row-major
  n: number;
  a: number;
  k: number;
  sigma0_m: number;
  minCommon: number;
  peakDbm: number;
  peakSigma: number | null;
  covScale: number;
  /** f3 errors' walk-long correlation ρ (member `walk_corr`; 0 when absent): caps a walk's WiFi information at 1/ρ scans. */
  walkCorr: number;
  /** False when the survey could not calibrate f3 (member `f3_calibrated` 0; true when absent): trackWalk leaves it out, as Python does. */
  f3Calibrated: boolean;
  /** Why f3 is left out (member `f3_note`; "" when absent). */
  f3Note: string;
  /** f3's heavy-tailed form (member `f3_robust` 1; false when absent, as those files were tracked). */
  robust: boolean;
  /** Its outlier rate ε (member `outlier_frac`; 0 when absent). */
  outlierFrac: number;
  scaleDb: Float64Array | null;
  scaleBy: Float64Array | null;
  peakXY: Map<string, [number, number]>;
}

function scalar(z: Map<string, NpyArray>, name: string, fallback: number): number {
  const a = z.get(name);
  return a ? Number((a.data as ArrayLike<number>)[0]) : fallback;
}

export async function loadFingerprints(bytes: Uint8Array, file = "fingerprints.npz"): Promise<FingerprintMap> {
  const z = await readNpz(bytes, file);
  const fmt = z.get("format")?.data;
  if (!Array.isArray(fmt) || fmt[0] !== "posefix-fingerprints") throw new NpzFormatError(file, "format", "not a posefix fingerprint file");
  for (const name of ["bssids", "p_xy_m", "rssi_dbm"]) if (!z.has(name)) throw new NpzFormatError(file, name, "missing member");
  const bssids = z.get("bssids")!.data as string[];
  const p = z.get("p_xy_m")!;
  const r = z.get("rssi_dbm")!;
  const n = p.shape[0];
  const a = bssids.length;
  if (r.shape[0] !== n || r.shape[1] !== a) throw new NpzFormatError(file, "rssi_dbm", `expected (${n}, ${a}), got (${r.shape})`);
  const pd = p.data as Float64Array;
  const px = Float64Array.from({ length: n }, (_, i) => pd[2 * i]);
  const py = Float64Array.from({ length: n }, (_, i) => pd[2 * i + 1]);
  const rssi = r.data instanceof Float32Array ? r.data : Float32Array.from(r.data as ArrayLike<number>);
  let peakSigma: number | null = null;
  if (z.has("peak_sigma_m")) {
    peakSigma = scalar(z, "peak_sigma_m", NaN);
    if (!(Number.isFinite(peakSigma) && peakSigma > 0)) throw new NpzFormatError(file, "peak_sigma_m", `must be a positive number of metres, got ${peakSigma}`);
  }
  const walkCorr = scalar(z, "walk_corr", 0);
  if (!(Number.isFinite(walkCorr) && walkCorr >= 0 && walkCorr < 1)) throw new NpzFormatError(file, "walk_corr", `must be a number in [0, 1), got ${walkCorr}`);
  const f3Calibrated = scalar(z, "f3_calibrated", 1);
  if (f3Calibrated !== 0 && f3Calibrated !== 1) throw new NpzFormatError(file, "f3_calibrated", `must be 0 or 1, got ${f3Calibrated}`);
  const note = z.get("f3_note")?.data;
  const robust = scalar(z, "f3_robust", 0);
  if (robust !== 0 && robust !== 1) throw new NpzFormatError(file, "f3_robust", `must be 0 or 1, got ${robust}`);
  const outlierFrac = scalar(z, "outlier_frac", 0);
  if (!(Number.isFinite(outlierFrac) && outlierFrac >= 0 && outlierFrac < 1)) throw new NpzFormatError(file, "outlier_frac", `must be a number in [0, 1), got ${outlierFrac}`);
  const sd = z.get("scale_match_db")?.data as Float64Array | undefined;
  const sb = z.get("scale_by_match")?.data as Float64Array | undefined;
  if (sd && sd.length && (!sb || sb.length !== sd.length)) throw new NpzFormatError(file, "scale_by_match", "shape differs from scale_match_db");
  const fp: FingerprintMap = {
    bssids, col: new Map(bssids.map((b, i) => [b, i])), px, py, rssi, n, a, k: 5, sigma0_m: 2, minCommon: 3, peakDbm: -55, peakSigma,
    covScale: scalar(z, "cov_scale", 1), walkCorr, f3Calibrated: f3Calibrated === 1,
    f3Note: Array.isArray(note) ? String(note[0]) : "", robust: robust === 1, outlierFrac, scaleDb: sd && sd.length ? Float64Array.from(sd) : null, scaleBy: sd && sd.length ? Float64Array.from(sb!) : null,
    peakXY: new Map(),
  };
  for (let j = 0; j < a; j++) {
    let best = 0;
    for (let i = 1; i < n; i++) if (rssi[i * a + j] > rssi[best * a + j]) best = i;
    if (n && rssi[best * a + j] >= fp.peakDbm) fp.peakXY.set(bssids[j], [px[best], py[best]]);
  }
  return fp;
}

const f32 = Math.fround;

/** numpy's pairwise float32 sum of x[0..n) (8 accumulators per block of up to 128). */
function pairwiseSum32(x: Float32Array | number[], lo: number, n: number): number {
  if (n < 8) {
    let s = -0;
    for (let i = 0; i < n; i++) s = f32(s + x[lo + i]);
    return s;
  }
  if (n <= 128) {
    const r = [x[lo], x[lo + 1], x[lo + 2], x[lo + 3], x[lo + 4], x[lo + 5], x[lo + 6], x[lo + 7]];
    let i = 8;
    for (; i < n - (n % 8); i += 8) for (let j = 0; j < 8; j++) r[j] = f32(r[j] + x[lo + i + j]);
    let res = f32(f32(f32(r[0] + r[1]) + f32(r[2] + r[3])) + f32(f32(r[4] + r[5]) + f32(r[6] + r[7])));
    for (; i < n; i++) res = f32(res + x[lo + i]);
    return res;
  }
  let n2 = Math.trunc(n / 2);
  n2 -= n2 % 8;
  return f32(pairwiseSum32(x, lo, n2) + pairwiseSum32(x, lo + n2, n - n2));
}

function scaleFor(fp: FingerprintMap, dBest: number): number {
  if (!fp.scaleDb || !fp.scaleBy) return fp.covScale;
  const xp = fp.scaleDb;
  const yp = fp.scaleBy;
  const n = xp.length;
  if (dBest <= xp[0]) return yp[0];
  if (dBest >= xp[n - 1]) return yp[n - 1];
  let j = 0;
  while (j + 1 < n && xp[j + 1] <= dBest) j++;
  if (xp[j] === dBest) return yp[j];
  return ((yp[j + 1] - yp[j]) / (xp[j + 1] - xp[j])) * (dBest - xp[j]) + yp[j];
}

/** The k-NN position (μ, Σ) of one scan, or null (fewer than 3 access points in common). */
export function predictScan(fp: FingerprintMap, scan: Map<string, number>): WifiFix | null {
  const v = new Float32Array(fp.a).fill(MISSING_DBM);
  let common = 0;
  for (const [b, r] of scan) {
    const j = fp.col.get(b);
    if (j !== undefined) (v[j] = r), common++;
  }
  if (common < fp.minCommon || fp.n === 0) return null;
  const heard: number[] = [];
  for (let j = 0; j < fp.a; j++) if (v[j] > MISSING_DBM) heard.push(j);
  const m = heard.length;
  const d = new Float32Array(fp.n);
  const sq = new Float32Array(m);
  for (let i = 0; i < fp.n; i++) {
    const row = i * fp.a;
    for (let q = 0; q < m; q++) {
      const diff = f32(fp.rssi[row + heard[q]] - v[heard[q]]);
      sq[q] = f32(diff * diff);
    }
    d[i] = f32(Math.sqrt(f32(pairwiseSum32(sq, 0, m) / m)));
  }
  const kk = Math.min(fp.k, fp.n);
  const order = Array.from({ length: fp.n }, (_, i) => i).sort((p, q) => d[p] - d[q] || p - q).slice(0, kk);
  const w = order.map((i) => f32(1 / f32(d[i] + 1)));
  let ws = -0;
  for (const x of w) ws = f32(ws + x);
  const wn = w.map((x) => f32(x / ws));
  let mx = 0;
  let my = 0;
  order.forEach((i, q) => ((mx += wn[q] * fp.px[i]), (my += wn[q] * fp.py[i])));
  let cxx = 0;
  let cxy = 0;
  let cyy = 0;
  order.forEach((i, q) => {
    const dx = fp.px[i] - mx;
    const dy = fp.py[i] - my;
    cxx += dx * wn[q] * dx;
    cxy += dx * wn[q] * dy;
    cyy += dy * wn[q] * dy;
  });
  const s = scaleFor(fp, Math.min(...order.map((i) => d[i])));
  const s0 = fp.sigma0_m * fp.sigma0_m;
  return { mean: [mx, my], cov: [(cxx + s0) * s, cxy * s, cxy * s, (cyy + s0) * s], eps: fp.robust ? fp.outlierFrac : 0 };
}

/** [(t_ms, bssid)] of the scans where a known access point peaks (one a scan, the strongest). */
export function scanPeaks(fp: FingerprintMap, scans: Scan[]): { t_ms: number; bssid: string }[] {
  const out: { t_ms: number; bssid: string }[] = [];
  scans.forEach((scan, j) => {
    let best: string | null = null;
    let bestR = -Infinity;
    for (const [b, r] of scan.rssi) {
      if (!fp.peakXY.has(b) || r < fp.peakDbm || r <= bestR) continue;
      const before = j > 0 ? (scans[j - 1].rssi.get(b) ?? MISSING_DBM) : MISSING_DBM;
      const after = j + 1 < scans.length ? (scans[j + 1].rssi.get(b) ?? MISSING_DBM) : MISSING_DBM;
      if (r > before && r >= after) (best = b), (bestR = r);
    }
    if (best !== null) out.push({ t_ms: scan.t_ms, bssid: best });
  });
  return out;
}
