/**
 * Modes of a position posterior and whether it has converged on one: the definition of
 * `posefix.mapmatch.modes` (its docstring has the reasoning), step for step.
 *
 *   m_b   = Σ_{v in bin b} p(v)                 (bins of `bin_m` from the lowest x and y with mass; vertex order)
 *   S     = the fewest bins holding `support` of the mass (mass descending, ties: lower bin index)
 *   modes = connected components of S dilated by one bin (8-neighbours), labelled in raster order
 *   mode j: mass M_j and mean over the vertices in bins of S in j; counted when M_j ≥ `min_mass`
 *           (at least the largest), by mass descending (ties: lower label)
 *   converged: M_main ≥ `converged_mass` and the whole posterior's 1σ major ≤ `converged_sigma_m`
 */

/** One mode holds ≥ 95 % of the mass (posefix.mapmatch.modes.CONVERGED_MASS). */
export const CONVERGED_MASS = 0.95;
/** The whole posterior's 1σ major semi-axis at most 5 m (CONVERGED_SIGMA_M). */
export const CONVERGED_SIGMA_M = 5;

export interface Mode {
  x: number;
  y: number;
  mass: number;
}

export interface Modes {
  /** Counted modes, mass descending. */
  modes: Mode[];
  /** Farthest counted mode's mean from the main one's (m; 0 with one). */
  spread_m: number;
  /** The whole posterior's 1σ major semi-axis (m). */
  sigma_major_m: number;
  converged: boolean;
}

export interface ModeOptions {
  bin_m?: number;
  support?: number;
  min_mass?: number;
  converged_mass?: number;
  converged_sigma_m?: number;
}

/** Bin of each vertex (row-major over the bins' grid) and the grid's shape. */
function binsOf(px: Float64Array, py: Float64Array, live: Int32Array, bin_m: number): { bin: Int32Array; rows: number; cols: number } {
  let lx = Infinity;
  let ly = Infinity;
  for (const v of live) {
    if (px[v] < lx) lx = px[v];
    if (py[v] < ly) ly = py[v];
  }
  const bx = new Int32Array(live.length);
  const by = new Int32Array(live.length);
  let cols = 0;
  let rows = 0;
  for (let i = 0; i < live.length; i++) {
    bx[i] = Math.floor((px[live[i]] - lx) / bin_m);
    by[i] = Math.floor((py[live[i]] - ly) / bin_m);
    if (bx[i] >= cols) cols = bx[i] + 1;
    if (by[i] >= rows) rows = by[i] + 1;
  }
  const bin = new Int32Array(live.length);
  for (let i = 0; i < live.length; i++) bin[i] = by[i] * cols + bx[i];
  return { bin, rows, cols };
}

/** The fewest bins holding `support` of the mass (as np.searchsorted over the cumulative sum). */
function supportBins(m: Float64Array, support: number): Uint8Array {
  const nz: number[] = [];
  for (let b = 0; b < m.length; b++) if (m[b] > 0) nz.push(b);
  // Bins without mass come last in the order and are never needed: the mass sums to 1 > support.
  nz.sort((a, b) => m[b] - m[a] || a - b);
  const keep = new Uint8Array(m.length);
  let cum = 0;
  for (const b of nz) {
    keep[b] = 1;
    cum += m[b];
    if (cum >= support) break;
  }
  return keep;
}

/** Components of `keep` dilated by one bin, 8-connected, labelled 1.. in raster order of their first cell. */
function labelDilated(keep: Uint8Array, rows: number, cols: number): { label: Int32Array; count: number } {
  const dil = new Uint8Array(rows * cols);
  for (let r = 0; r < rows; r++) {
    for (let c = 0; c < cols; c++) {
      if (!keep[r * cols + c]) continue;
      for (let i = Math.max(r - 1, 0); i <= Math.min(r + 1, rows - 1); i++) for (let j = Math.max(c - 1, 0); j <= Math.min(c + 1, cols - 1); j++) dil[i * cols + j] = 1;
    }
  }
  const label = new Int32Array(rows * cols);
  const stack = new Int32Array(rows * cols);
  let count = 0;
  for (let s = 0; s < rows * cols; s++) {
    if (!dil[s] || label[s]) continue;
    label[s] = ++count;
    let top = 0;
    stack[top++] = s;
    while (top) {
      const q = stack[--top];
      const r = Math.trunc(q / cols);
      const c = q - r * cols;
      for (let i = Math.max(r - 1, 0); i <= Math.min(r + 1, rows - 1); i++) {
        for (let j = Math.max(c - 1, 0); j <= Math.min(c + 1, cols - 1); j++) {
          const t = i * cols + j;
          if (dil[t] && !label[t]) (label[t] = count), (stack[top++] = t);
        }
      }
    }
  }
  return { label, count };
}

/** 1σ major semi-axis of weights `w` (sum 1, over the live vertices) as posefix.mapmatch.modes._sigma_major. */
function sigmaMajor(px: Float64Array, py: Float64Array, live: Int32Array, w: Float64Array): number {
  let mx = 0;
  let my = 0;
  for (let i = 0; i < live.length; i++) (mx += w[i] * px[live[i]]), (my += w[i] * py[live[i]]);
  let cxx = 0;
  let cxy = 0;
  let cyy = 0;
  for (let i = 0; i < live.length; i++) {
    const dx = px[live[i]] - mx;
    const dy = py[live[i]] - my;
    cxx += dx * w[i] * dx;
    cxy += dx * w[i] * dy;
    cyy += dy * w[i] * dy;
  }
  const tr = cxx + cyy;
  const det = cxx * cyy - cxy * cxy;
  return Math.sqrt(Math.max(tr / 2 + Math.sqrt(Math.max((tr * tr) / 4 - det, 0)), 0));
}

/**
 * Modes of a distribution over the vertices: `weight[v]` (any scale, > 0) on the vertices
 * `live` (ascending), positions `px`/`py`.
 */
export function posteriorModes(px: Float64Array, py: Float64Array, weight: Float64Array, live: Int32Array, opts: ModeOptions = {}): Modes {
  const bin_m = opts.bin_m ?? 2;
  const support = opts.support ?? 0.995;
  const minMass = opts.min_mass ?? 0.01;
  let total = 0;
  for (const v of live) total += weight[v];
  if (!(total > 0)) throw new Error("posteriorModes: the distribution has no mass");
  const w = new Float64Array(live.length);
  for (let i = 0; i < live.length; i++) w[i] = weight[live[i]] / total;
  const { bin, rows, cols } = binsOf(px, py, live, bin_m);
  const m = new Float64Array(rows * cols);
  for (let i = 0; i < live.length; i++) m[bin[i]] += w[i];
  const keep = supportBins(m, support);
  const { label, count } = labelDilated(keep, rows, cols);
  const mass = new Float64Array(count + 1);
  const sx = new Float64Array(count + 1);
  const sy = new Float64Array(count + 1);
  for (let i = 0; i < live.length; i++) {
    const l = keep[bin[i]] ? label[bin[i]] : 0;
    mass[l] += w[i];
    sx[l] += w[i] * px[live[i]];
    sy[l] += w[i] * py[live[i]];
  }
  let sel: number[] = [];
  for (let l = 1; l <= count; l++) if (mass[l] >= minMass) sel.push(l);
  if (!sel.length) {
    let best = 1;
    for (let l = 2; l <= count; l++) if (mass[l] > mass[best]) best = l;
    sel = [best];
  }
  sel.sort((a, b) => mass[b] - mass[a] || a - b);
  const modes = sel.map((l) => ({ x: sx[l] / mass[l], y: sy[l] / mass[l], mass: mass[l] }));
  let spread = 0;
  for (const md of modes) spread = Math.max(spread, Math.sqrt((md.x - modes[0].x) ** 2 + (md.y - modes[0].y) ** 2));
  const sigma = sigmaMajor(px, py, live, w);
  const converged = modes[0].mass >= (opts.converged_mass ?? CONVERGED_MASS) && sigma <= (opts.converged_sigma_m ?? CONVERGED_SIGMA_M);
  return { modes, spread_m: spread, sigma_major_m: sigma, converged };
}
