/**
 * The posefix map-matching model (docs/mapmatch.md, "Model file format"), read from the
 * same bytes the server writes (`posefix.mapmatch.model`), and the dense transition
 * tables rebuilt from it:
 *
 *   vertex centre  p_v = (x0 + (col_v + ½)·c, y0 + (row_v + ½)·c)
 *   succ[u, k] = v  when bit k of trans_mask[u] is set and v is the vertex at ij_u + offsets[k]
 *   pred[v, k] = u  the same pair seen from v (stored with n, the filters' sentinel, for none)
 */
import { type NpyArray, NpzFormatError, readNpz } from "./npz";

export const MODEL_FORMAT = "posefix-mapmatch";
export const MODEL_VERSION = 1;
/** Correlation time (s) of WiFi errors for files with four sigmas (posefix.mapmatch.features.WIFI_CORR_S). */
export const DEFAULT_WIFI_CORR_S = 20;

export interface StepModel {
  height_m: number;
  alpha_s: number;
  beta: number;
  gamma_m: number;
  heading_bias_rad: number;
  min_len_m: number;
  max_len_m: number;
}

export interface Sigmas {
  len_m: number;
  heading_rad: number;
  window_steps: number;
  min_span_m: number;
  wifi_corr_s: number;
}

export interface Graph {
  cell_m: number;
  x0_m: number;
  y0_m: number;
  rows: number;
  cols: number;
  n: number; // vertices
  k: number; // step offsets
  px: Float64Array; // vertex centres
  py: Float64Array;
  offX: Float64Array; // offsets in metres
  offY: Float64Array;
  /** succ[u * k + j]: vertex reached from u by offset j, or -1. */
  succ: Int32Array;
  /**
   * predV[v * k + j]: vertex u with u + offset j = v, or n when there is none (the filters'
   * value buffers hold a neutral sentinel at index n). One row of K per vertex: a filter
   * step reads a vertex's predecessors together. 16-bit when the floor has under 65 535
   * vertices: half the bytes a step streams through the cache.
   */
  predV: Uint16Array | Int32Array;
}

export interface TrackerModel {
  graph: Graph;
  georef: [number, number, number, number] | null; // lon0, lat0, dlon_per_m, dlat_per_m
  step: StepModel;
  weights: { f1: number; f2: number; f3: number; f4: number };
  sigmas: Sigmas;
  beam: number | null;
  /** Covariance scale of the reported ellipses (optional member `ellipse_scale`; 1 when absent). */
  ellipseScale: number;
  bytes: number;
}

function member(z: Map<string, NpyArray>, file: string, name: string): NpyArray {
  const a = z.get(name);
  if (!a) throw new NpzFormatError(file, name, "missing member");
  return a;
}

function numbers(z: Map<string, NpyArray>, file: string, name: string): number[] {
  const a = member(z, file, name);
  if (Array.isArray(a.data)) throw new NpzFormatError(file, name, `expected numbers, got ${a.dtype}`);
  return Array.from(a.data as ArrayLike<number>);
}

/** Dense successor and predecessor tables from the vertices and the transition bits. */
export function transitionTables(ij: ArrayLike<number>, transMask: ArrayLike<number>, offsets: ArrayLike<number>, rows: number, cols: number): { succ: Int32Array; predV: Uint16Array | Int32Array } {
  const n = transMask.length;
  const k = offsets.length / 2;
  const grid = new Int32Array(rows * cols).fill(-1);
  for (let v = 0; v < n; v++) grid[ij[2 * v + 1] * cols + ij[2 * v]] = v;
  const succ = new Int32Array(n * k).fill(-1);
  const predV = n < 0xffff ? new Uint16Array(n * k).fill(n) : new Int32Array(n * k).fill(n);
  for (let j = 0; j < k; j++) {
    const dc = offsets[2 * j];
    const dr = offsets[2 * j + 1];
    for (let u = 0; u < n; u++) {
      if (((transMask[u] >>> j) & 1) === 0) continue;
      const c = ij[2 * u] + dc;
      const r = ij[2 * u + 1] + dr;
      if (c < 0 || c >= cols || r < 0 || r >= rows) continue;
      const v = grid[r * cols + c];
      if (v < 0) continue;
      succ[u * k + j] = v;
      predV[v * k + j] = u;
    }
  }
  return { succ, predV };
}

/** Read a model file's bytes (`GET /api/v1/floorplans/{id}/model`); errors name file and member. */
export async function loadModel(bytes: Uint8Array, file = "model.npz"): Promise<TrackerModel> {
  const z = await readNpz(bytes, file);
  const fmt = member(z, file, "format").data;
  if (!Array.isArray(fmt) || fmt[0] !== MODEL_FORMAT) throw new NpzFormatError(file, "format", `expected '${MODEL_FORMAT}', got ${JSON.stringify(fmt)}`);
  const version = numbers(z, file, "version")[0];
  if (version !== MODEL_VERSION) throw new NpzFormatError(file, "version", `unsupported version ${version}`);
  const grid = numbers(z, file, "grid");
  if (grid.length !== 5) throw new NpzFormatError(file, "grid", `expected 5 numbers, got ${grid.length}`);
  const [cell, x0, y0, rows, cols] = grid;
  const ijA = member(z, file, "ij");
  const ij = ijA.data as ArrayLike<number>;
  const mask = member(z, file, "trans_mask").data as ArrayLike<number>;
  const off = member(z, file, "offsets").data as ArrayLike<number>;
  const n = mask.length;
  if (ijA.shape.length !== 2 || ijA.shape[0] !== n || ijA.shape[1] !== 2) throw new NpzFormatError(file, "ij", `expected (${n}, 2), got (${ijA.shape})`);
  const k = off.length / 2;
  if (k < 1 || k > 32) throw new NpzFormatError(file, "offsets", `expected 1..32 offsets, got ${k}`);
  const px = new Float64Array(n);
  const py = new Float64Array(n);
  for (let v = 0; v < n; v++) {
    px[v] = x0 + (ij[2 * v] + 0.5) * cell;
    py[v] = y0 + (ij[2 * v + 1] + 0.5) * cell;
  }
  const offX = new Float64Array(k);
  const offY = new Float64Array(k);
  for (let j = 0; j < k; j++) (offX[j] = off[2 * j] * cell), (offY[j] = off[2 * j + 1] * cell);
  const { succ, predV } = transitionTables(ij, mask, off, rows, cols);
  const geo = numbers(z, file, "georef");
  const sm = numbers(z, file, "step_model");
  if (sm.length !== 7) throw new NpzFormatError(file, "step_model", `expected 7 numbers, got ${sm.length}`);
  const w = numbers(z, file, "weights");
  if (w.length !== 4) throw new NpzFormatError(file, "weights", `expected 4 numbers, got ${w.length}`);
  const s = numbers(z, file, "sigmas");
  if (s.length !== 4 && s.length !== 5) throw new NpzFormatError(file, "sigmas", `expected 4 or 5 numbers, got ${s.length}`);
  const tau = s.length === 5 ? s[4] : DEFAULT_WIFI_CORR_S;
  if (!(Number.isFinite(tau) && tau >= 0)) throw new NpzFormatError(file, "sigmas", `wifi_corr_s (5th entry) must be a number of seconds >= 0, got ${tau}`);
  const beam = numbers(z, file, "beam")[0];
  const ell = z.has("ellipse_scale") ? numbers(z, file, "ellipse_scale")[0] : 1;
  if (!(Number.isFinite(ell) && ell > 0)) throw new NpzFormatError(file, "ellipse_scale", `must be a positive number, got ${ell}`);
  return {
    graph: { cell_m: cell, x0_m: x0, y0_m: y0, rows, cols, n, k, px, py, offX, offY, succ, predV },
    georef: geo.length === 4 ? [geo[0], geo[1], geo[2], geo[3]] : null,
    step: { height_m: sm[0], alpha_s: sm[1], beta: sm[2], gamma_m: sm[3], heading_bias_rad: sm[4], min_len_m: sm[5], max_len_m: sm[6] },
    weights: { f1: w[0], f2: w[1], f3: w[2], f4: w[3] },
    sigmas: { len_m: s[0], heading_rad: s[1], window_steps: Math.trunc(s[2]), min_span_m: s[3], wifi_corr_s: tau },
    beam: Number.isFinite(beam) ? beam : null,
    ellipseScale: ell,
    bytes: bytes.length,
  };
}

/** Floor metres -> [lon, lat] with the model's geo-reference (null when it has none). */
export function toLonLat(m: TrackerModel, x: number, y: number): [number, number] | null {
  if (!m.georef) return null;
  const [lon0, lat0, dlon, dlat] = m.georef;
  return [lon0 + x * dlon, lat0 + y * dlat];
}
