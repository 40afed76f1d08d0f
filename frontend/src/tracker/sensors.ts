/**
 * Phone sensors to steps, as `posefix.mapmatch.sensors` does it (same numbers, same order):
 *
 *   a_t      = |acc_t| − g                                  (g = 9.80665 m/s²)
 *   â        = filtfilt(Butterworth order 2, cutoff 2 Hz) a  (odd extension of 9 samples, steady-state start)
 *   steps    = peaks of â with prominence ≥ 2 m/s², at least 0.3 s apart (higher peaks first)
 *   f_i      = median(1/gap_{i−1}, 1/gap_i, 1/gap_{i+1})     (gap > 1 s counts as 1.8 Hz)
 *   l_i      = clip(h·(α·f_i + β) + γ, l_min, l_max)
 *   θ        = atan2(1 − 2(x² + z²), 2(xy − zw))             (device y axis from the rotation vector q = x,y,z,w)
 *   step_i   = l_i · (cos(θ_i + b), sin(θ_i + b))            (b = the model's heading bias)
 *
 * θ at a step is the unwrapped rotation-vector heading interpolated at its time. A WiFi
 * scan is the lines delivered together; entries last seen more than 3 s before the scan's
 * newest are dropped and the scan is timed at the median last-seen time of those kept.
 */
import type { StepModel } from "./model";

export const GRAVITY_MPS2 = 9.80665;
export const WIFI_MAX_AGE_MS = 3000;

export class WalkFormatError extends Error {
  constructor(
    readonly file: string,
    readonly line: number,
    readonly field: string,
    message: string,
  ) {
    super(`${file}:${line}: field ${field}: ${message}`);
    this.name = "WalkFormatError";
  }
}

/** Samples as parallel arrays: times (ms) and three values each. */
export interface Samples {
  t: Float64Array;
  x: Float64Array;
  y: Float64Array;
  z: Float64Array;
}

export interface WifiRow {
  t_ms: number; // delivery (line) time
  bssid: string;
  rssi_dbm: number;
  seen_ms: number;
}

export interface Walk {
  file: string;
  acc: Samples;
  rotvec: Samples;
  wifi: WifiRow[];
  waypoints: { t_ms: number; x_m: number; y_m: number }[];
}

export interface Steps {
  t_ms: Float64Array;
  freq_hz: Float64Array;
  heading_rad: Float64Array;
}

function samples(rows: number[][]): Samples {
  const n = rows.length;
  const s = { t: new Float64Array(n), x: new Float64Array(n), y: new Float64Array(n), z: new Float64Array(n) };
  rows.forEach((r, i) => ((s.t[i] = r[0]), (s.x[i] = r[1]), (s.y[i] = r[2]), (s.z[i] = r[3])));
  return s;
}

const INT = /^\s*[+-]?\d+\s*$/;

function num(v: string | undefined): number {
  if (v === undefined || v.trim() === "") return NaN;
  return Number(v);
}

/** Parse a competition path file (the accelerometer, rotation vector, WiFi and waypoint lines). */
export function parseWalk(text: string, file = "walk.txt"): Walk {
  const acc: number[][] = [];
  const rot: number[][] = [];
  const wifi: WifiRow[] = [];
  const waypoints: Walk["waypoints"] = [];
  const lines = text.split("\n");
  for (let i = 0; i < lines.length; i++) {
    const line = lines[i].replace(/\r$/, "");
    if (!line || line.startsWith("#")) continue;
    const parts = line.split("\t");
    const lineNo = i + 1;
    if (parts.length < 2) throw new WalkFormatError(file, lineNo, "type", "expected 'unix_ms<TAB>TYPE ...'");
    if (!INT.test(parts[0])) throw new WalkFormatError(file, lineNo, "unix_ms", `not an integer: '${parts[0]}'`);
    const t = Number(parts[0]);
    const kind = parts[1];
    if (kind === "TYPE_ACCELEROMETER" || kind === "TYPE_ROTATION_VECTOR") {
      const v = [num(parts[2]), num(parts[3]), num(parts[4])];
      if (parts.length < 5) throw new WalkFormatError(file, lineNo, kind, "expected 3 values");
      if (v.some((x) => Number.isNaN(x))) throw new WalkFormatError(file, lineNo, kind, "values must be numbers");
      (kind === "TYPE_ACCELEROMETER" ? acc : rot).push([t, ...v]);
    } else if (kind === "TYPE_WIFI") {
      if (parts.length < 5) throw new WalkFormatError(file, lineNo, "TYPE_WIFI", "expected ssid, bssid, rssi");
      const rssi = num(parts[4]);
      if (Number.isNaN(rssi)) throw new WalkFormatError(file, lineNo, "rssi", `not a number: '${parts[4]}'`);
      let seen = t;
      if (parts.length >= 7 && parts[6].trim()) {
        if (!INT.test(parts[6])) throw new WalkFormatError(file, lineNo, "last_seen_timestamp", `not an integer: '${parts[6]}'`);
        seen = Number(parts[6]);
      }
      wifi.push({ t_ms: t, bssid: parts[3], rssi_dbm: rssi, seen_ms: seen });
    } else if (kind === "TYPE_WAYPOINT") {
      const x = num(parts[2]);
      const y = num(parts[3]);
      if (Number.isNaN(x) || Number.isNaN(y)) throw new WalkFormatError(file, lineNo, "TYPE_WAYPOINT", "expected x y in metres");
      waypoints.push({ t_ms: t, x_m: x, y_m: y });
    }
  }
  if (acc.length < 10) throw new WalkFormatError(file, 0, "acc", "too few samples to detect steps");
  if (rot.length < 10) throw new WalkFormatError(file, 0, "rotvec", "too few samples to detect steps");
  return { file, acc: samples(acc), rotvec: samples(rot), wifi, waypoints };
}

// ---- numpy's semantics where they matter ---------------------------------------------

/** numpy's float `%` (sign of the divisor, computed from fmod). */
export function pyMod(a: number, m: number): number {
  let r = a % m;
  if (r !== 0 && r < 0 !== m < 0) r += m;
  return r;
}

/** numpy's `round` (halves to even). */
export function roundHalfEven(x: number): number {
  const r = Math.round(x);
  return r - x === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

export function wrapAngle(a: number): number {
  return pyMod(a + Math.PI, 2 * Math.PI) - Math.PI;
}

/** numpy's `interp` of one point (xp increasing; ends clamped). */
export function interp(x: number, xp: ArrayLike<number>, fp: ArrayLike<number>): number {
  const n = xp.length;
  if (x > xp[n - 1]) return fp[n - 1];
  if (x < xp[0]) return fp[0];
  const j = lastAtOrBelow(x, xp);
  if (j === n - 1 || xp[j] === x) return fp[j];
  const slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
  return slope * (x - xp[j]) + fp[j];
}

/** Largest j with xp[j] <= x (xp sorted, x >= xp[0]). */
function lastAtOrBelow(x: number, xp: ArrayLike<number>): number {
  let lo = 0;
  let hi = xp.length - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (xp[mid] <= x) lo = mid;
    else hi = mid - 1;
  }
  return lo;
}

export function unwrap(p: Float64Array): Float64Array {
  const out = new Float64Array(p.length);
  if (!p.length) return out;
  out[0] = p[0];
  let corr = 0;
  for (let i = 1; i < p.length; i++) {
    const dd = p[i] - p[i - 1];
    let ddmod = pyMod(dd + Math.PI, 2 * Math.PI) - Math.PI;
    if (ddmod === -Math.PI && dd > 0) ddmod = Math.PI;
    if (Math.abs(dd) >= Math.PI) corr += ddmod - dd;
    out[i] = p[i] + corr;
  }
  return out;
}

function median(values: number[]): number {
  const s = [...values].sort((a, b) => a - b);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}

// ---- step detection -------------------------------------------------------------------

/** Order-2 Butterworth low-pass (b, a) for a normalised cutoff wn (1 = Nyquist), bilinear with pre-warping. */
export function butter2(wn: number): { b: [number, number, number]; a: [number, number, number] } {
  const k = Math.tan((Math.PI * wn) / 2);
  const norm = 1 / (1 + Math.SQRT2 * k + k * k);
  const b0 = k * k * norm;
  return { b: [b0, 2 * b0, b0], a: [1, 2 * (k * k - 1) * norm, (1 - Math.SQRT2 * k + k * k) * norm] };
}

function lfilter(b: number[], a: number[], x: Float64Array, z0: number, z1: number): Float64Array {
  const y = new Float64Array(x.length);
  for (let i = 0; i < x.length; i++) {
    const xi = x[i];
    const yi = b[0] * xi + z0;
    z0 = b[1] * xi - a[1] * yi + z1;
    z1 = b[2] * xi - a[2] * yi;
    y[i] = yi;
  }
  return y;
}

/** scipy.signal.filtfilt with its defaults (odd extension of 3·max(len a, len b) samples, lfilter_zi start). */
export function filtfilt(b: number[], a: number[], x: Float64Array): Float64Array {
  const pad = 9;
  const n = x.length;
  if (n <= pad) throw new Error(`filtfilt needs more than ${pad} samples, got ${n}`);
  const ext = new Float64Array(n + 2 * pad);
  for (let i = 0; i < pad; i++) ext[i] = 2 * x[0] - x[pad - i];
  ext.set(x, pad);
  for (let i = 0; i < pad; i++) ext[pad + n + i] = 2 * x[n - 1] - x[n - 2 - i];
  // lfilter_zi: the state of a unit step's steady state.
  const B0 = b[1] - a[1] * b[0];
  const B1 = b[2] - a[2] * b[0];
  const zi0 = (B0 + B1) / (1 + a[1] + a[2]);
  const zi1 = B1 - a[2] * zi0;
  const fwd = lfilter(b, a, ext, zi0 * ext[0], zi1 * ext[0]);
  fwd.reverse();
  const y0 = fwd[0];
  const back = lfilter(b, a, fwd, zi0 * y0, zi1 * y0);
  back.reverse();
  return back.slice(pad, pad + n);
}

/** scipy.signal.find_peaks(x, distance=d, prominence=p) (plateaus at their middle). */
export function findPeaks(x: Float64Array, distance: number, minProminence: number): number[] {
  const peaks: number[] = [];
  const n = x.length;
  let i = 1;
  while (i < n - 1) {
    if (x[i - 1] < x[i]) {
      let ahead = i + 1;
      while (ahead < n - 1 && x[ahead] === x[i]) ahead++;
      if (x[ahead] < x[i]) {
        peaks.push((i + ahead - 1) >> 1);
        i = ahead;
      }
    }
    i++;
  }
  // Distance: keep the highest, drop neighbours closer than `distance` samples, and so on.
  const keep = new Uint8Array(peaks.length).fill(1);
  const order = peaks.map((_, j) => j).sort((p, q) => x[peaks[p]] - x[peaks[q]] || p - q);
  for (let r = order.length - 1; r >= 0; r--) {
    const j = order[r];
    if (!keep[j]) continue;
    for (let k = j - 1; k >= 0 && peaks[j] - peaks[k] < distance; k--) keep[k] = 0;
    for (let k = j + 1; k < peaks.length && peaks[k] - peaks[j] < distance; k++) keep[k] = 0;
  }
  const out: number[] = [];
  peaks.forEach((p, j) => {
    if (!keep[j]) return;
    const h = x[p];
    let leftMin = h;
    for (let q = p; q >= 0 && x[q] <= h; q--) if (x[q] < leftMin) leftMin = x[q];
    let rightMin = h;
    for (let q = p; q < n && x[q] <= h; q++) if (x[q] < rightMin) rightMin = x[q];
    if (h - Math.max(leftMin, rightMin) >= minProminence) out.push(p);
  });
  return out;
}

/** Step times (ms) and frequencies (Hz) from accelerometer samples. */
export function detectSteps(acc: Samples, minIntervalS = 0.3, minProminence = 2.0, cutoffHz = 2.0): { t_ms: Float64Array; freq_hz: Float64Array } {
  const t = acc.t;
  const n = t.length;
  if (n < 16) return { t_ms: new Float64Array(0), freq_hz: new Float64Array(0) };
  const diffs: number[] = [];
  for (let i = 1; i < n; i++) diffs.push(t[i] - t[i - 1]);
  const dt = Math.max(median(diffs) / 1000, 1e-3);
  const a = new Float64Array(n);
  for (let i = 0; i < n; i++) a[i] = Math.sqrt(acc.x[i] * acc.x[i] + acc.y[i] * acc.y[i] + acc.z[i] * acc.z[i]) - GRAVITY_MPS2;
  const { b, a: af } = butter2(Math.min(cutoffHz * 2 * dt, 0.99));
  const s = filtfilt(b, af, a);
  const idx = findPeaks(s, Math.max(1, Math.trunc(minIntervalS / dt)), minProminence);
  const tm = Float64Array.from(idx, (i) => Math.trunc(t[i]));
  const k = tm.length;
  if (k < 2) return { t_ms: tm, freq_hz: new Float64Array(k).fill(1.8) };
  const f = new Float64Array(k);
  for (let i = 1; i < k; i++) {
    const gap = (tm[i] - tm[i - 1]) / 1000;
    f[i] = gap > 1 ? 1.8 : 1 / Math.max(gap, 1e-3);
  }
  f[0] = f[1];
  const freq = new Float64Array(k);
  for (let i = 0; i < k; i++) {
    const p = f[Math.max(i - 1, 0)];
    const c = f[i];
    const q = f[Math.min(i + 1, k - 1)];
    freq[i] = Math.max(Math.min(p, c), Math.min(Math.max(p, c), q));
  }
  return { t_ms: tm, freq_hz: freq };
}

/** Heading (rad, CCW from east) of the device y axis for a rotation vector (sin(θ/2)·axis). */
export function headingFromRotationVector(x: number, y: number, z: number): number {
  const w = Math.sqrt(Math.max(1 - (x * x + y * y + z * z), 0));
  const nq = Math.sqrt(x * x + y * y + z * z + w * w);
  const [qx, qy, qz, qw] = [x / nq, y / nq, z / nq, w / nq];
  return Math.atan2(1 - 2 * (qx * qx + qz * qz), 2 * (qx * qy - qz * qw));
}

/** Sensor heading at each time (unwrapped between samples, wrapped to ±π). */
export function headingsAt(t_ms: ArrayLike<number>, headT: Float64Array, head: Float64Array): Float64Array {
  const un = unwrap(head);
  return Float64Array.from(t_ms, (t) => wrapAngle(interp(t, headT, un)));
}

export function stepsFromWalk(walk: Walk): Steps {
  const { t_ms, freq_hz } = detectSteps(walk.acc);
  const r = walk.rotvec;
  const head = Float64Array.from(r.t, (_, i) => headingFromRotationVector(r.x[i], r.y[i], r.z[i]));
  return { t_ms, freq_hz, heading_rad: headingsAt(t_ms, r.t, head) };
}

export function stepLength(m: StepModel, f: number): number {
  const l = m.height_m * (m.alpha_s * f + m.beta) + m.gamma_m;
  return Math.min(Math.max(l, m.min_len_m), m.max_len_m);
}

/** Floor-frame step vectors (m): length from the frequency, heading plus the model's bias. */
export function stepVector(m: StepModel, freq_hz: number, heading_rad: number): [number, number] {
  const l = stepLength(m, freq_hz);
  const th = heading_rad + m.heading_bias_rad;
  return [l * Math.cos(th), l * Math.sin(th)];
}

export interface Scan {
  t_ms: number;
  rssi: Map<string, number>;
}

/** WiFi rows grouped into scans (by delivery time), stale entries dropped, timed when measured. */
export function wifiScans(rows: WifiRow[], maxAgeMs: number = WIFI_MAX_AGE_MS): Scan[] {
  const groups = new Map<number, WifiRow[]>();
  for (const r of rows) {
    const g = groups.get(r.t_ms);
    if (g) g.push(r);
    else groups.set(r.t_ms, [r]);
  }
  const out: Scan[] = [];
  for (const g of groups.values()) {
    const newest = Math.max(...g.map((r) => r.seen_ms));
    const kept = g.filter((r) => r.seen_ms >= newest - maxAgeMs);
    const rssi = new Map<string, number>();
    for (const r of kept) rssi.set(r.bssid, r.rssi_dbm);
    out.push({ t_ms: Math.trunc(median(kept.map((r) => r.seen_ms))), rssi });
  }
  return out.map((s, i) => [s, i] as const).sort((p, q) => p[0].t_ms - q[0].t_ms || p[1] - q[1]).map((p) => p[0]);
}
