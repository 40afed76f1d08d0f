/**
 * Live tracking from a phone's own sensors: samples arrive one by one, steps are detected
 * on the recent buffer and fed to the tracker as they become final.
 *
 * Step detection is the batch one (sensors.ts: a forward-backward low-pass, peaks with
 * ≥ 2 m/s² prominence), run again over the last `windowS` seconds whenever `everyS`
 * seconds of new samples have come in. A step is final — fed once, never revised — when it
 * lies more than `horizonS` before the newest sample (the filter's edge and the next step,
 * which the step frequency needs, are then in the buffer) and after the buffer's first
 * `horizonS` seconds; `finish()` feeds the rest. Headings are those of the orientation
 * samples, unwrapped and interpolated at the step's time, as for a walk file.
 *
 * Orientation sources, all reduced to the heading θ of the device y axis, CCW from east:
 *   rotation vector / quaternion (x, y, z, w), device → east-north-up:  θ = atan2(1 − 2(x² + z²), 2(xy − zw))
 *   DeviceOrientation (α, β, γ) absolute, R = R_z(α)·R_x(β)·R_y(γ):     θ = atan2(cos α cos β, −sin α cos β)
 *   iOS webkitCompassHeading h (degrees clockwise from north):         θ = π/2 − h
 */
import type { TrackerModel } from "./model";
import { type Samples, detectSteps, headingsAt, stepVector } from "./sensors";
import type { Mode } from "./modes";
import { type TrackPoint, Tracker, type TrackerOptions } from "./tracker";

const DEG = Math.PI / 180;

export function headingFromQuaternion(x: number, y: number, z: number, w: number): number {
  return Math.atan2(1 - 2 * (x * x + z * z), 2 * (x * y - z * w));
}

export function headingFromEuler(alphaDeg: number, betaDeg: number): number {
  const a = alphaDeg * DEG;
  const cb = Math.cos(betaDeg * DEG);
  return Math.atan2(Math.cos(a) * cb, -Math.sin(a) * cb);
}

export function headingFromCompass(compassDeg: number): number {
  return Math.PI / 2 - compassDeg * DEG;
}

/** A growing buffer of samples (times in ms), trimmed to the last `keepMs`. */
class Buffer {
  t: number[] = [];
  v: number[][] = [];
  trimmed = false; // samples were dropped from the front
  push(t: number, values: number[]) {
    this.t.push(t);
    this.v.push(values);
  }
  trim(fromMs: number) {
    let i = 0;
    while (i < this.t.length && this.t[i] < fromMs) i++;
    if (i) (this.t = this.t.slice(i)), (this.v = this.v.slice(i)), (this.trimmed = true);
  }
}

export interface LiveStep {
  t_ms: number;
  freq_hz: number;
  heading_rad: number;
}

export class LiveSteps {
  private acc = new Buffer();
  private head = new Buffer();
  private lastRun = -Infinity;
  private lastFed = -Infinity;

  constructor(
    readonly windowS = 30,
    readonly horizonS = 1.5,
    readonly everyS = 0.5,
  ) {}

  addMotion(t_ms: number, ax: number, ay: number, az: number): void {
    this.acc.push(t_ms, [ax, ay, az]);
  }

  addHeading(t_ms: number, heading_rad: number): void {
    this.head.push(t_ms, [heading_rad]);
  }

  get newest(): number {
    return this.acc.t.length ? this.acc.t[this.acc.t.length - 1] : -Infinity;
  }

  /** Steps that became final since the last call (all remaining ones with `final`). */
  poll(final = false): LiveStep[] {
    const end = this.newest;
    if (!final && end - this.lastRun < this.everyS * 1000) return [];
    this.lastRun = end;
    const n = this.acc.t.length;
    if (n < 16 || this.head.t.length < 2) return [];
    const s: Samples = {
      t: Float64Array.from(this.acc.t),
      x: Float64Array.from(this.acc.v, (r) => r[0]),
      y: Float64Array.from(this.acc.v, (r) => r[1]),
      z: Float64Array.from(this.acc.v, (r) => r[2]),
    };
    const { t_ms, freq_hz } = detectSteps(s);
    // Near a trimmed buffer's start the low-pass has an edge: those steps were fed before.
    const lo = Math.max(this.lastFed, this.acc.trimmed ? this.acc.t[0] + this.horizonS * 1000 : -Infinity);
    const hi = final ? Infinity : end - this.horizonS * 1000;
    const idx: number[] = [];
    for (let i = 0; i < t_ms.length; i++) if (t_ms[i] > lo && t_ms[i] <= hi) idx.push(i);
    const headings = headingsAt(idx.map((i) => t_ms[i]), Float64Array.from(this.head.t), Float64Array.from(this.head.v, (r) => r[0]));
    const out = idx.map((i, j) => ({ t_ms: t_ms[i], freq_hz: freq_hz[i], heading_rad: headings[j] }));
    if (out.length) this.lastFed = out[out.length - 1].t_ms;
    const keepFrom = end - this.windowS * 1000;
    this.acc.trim(keepFrom);
    this.head.trim(keepFrom - 2000);
    return out;
  }
}

export interface LivePoint extends TrackPoint {
  dr: [number, number];
  /** The posterior's modes, mass descending, and how far the farthest is from the main one (m). */
  modes: Mode[];
  spread_m: number;
  converged: boolean;
}

/** Sensors in, positions out: LiveSteps feeding a Tracker. */
export class LiveSession {
  readonly steps = new LiveSteps();
  readonly tracker: Tracker;
  readonly points: LivePoint[] = [];
  private dr: [number, number];

  constructor(
    readonly model: TrackerModel,
    opts: TrackerOptions = {},
  ) {
    this.tracker = new Tracker(model, opts);
    // Dead reckoning needs a start; without one there is none to draw (NaN).
    this.dr = opts.start ? [opts.start[0], opts.start[1]] : [NaN, NaN];
    this.points.push(this.point({ t_ms: opts.t0_ms ?? 0, summary: this.tracker.summary(), vertex: -1 }));
  }

  private point(tp: TrackPoint): LivePoint {
    const m = this.tracker.modes();
    return { ...tp, dr: [this.dr[0], this.dr[1]], modes: m.modes, spread_m: m.spread_m, converged: m.converged };
  }

  /** Feed the steps that became final; returns the new points. */
  update(final = false): LivePoint[] {
    const fresh: LivePoint[] = [];
    for (const s of this.steps.poll(final)) {
      const [sx, sy] = stepVector(this.model.step, s.freq_hz, s.heading_rad);
      this.dr = [this.dr[0] + sx, this.dr[1] + sy];
      const p = this.point(this.tracker.step(sx, sy, s.t_ms));
      this.points.push(p);
      fresh.push(p);
    }
    return fresh;
  }
}
