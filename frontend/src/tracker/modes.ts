/**
 * Modes of a position posterior and whether it has converged on one: the definition of
 * `posefix.mapmatch.modes` (its docstring has the reasoning), step for step.
 *
 *   m_b   = Σ_{v in bin b} p(v)                 (bins of `bin_m` from the lowest x and y of all vertices; vertex order)
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

/** The bins of a floor's vertices and scratch space for its steps (one per positions array and bin size). */
interface BinGrid {
  bin_m: number;
  bin: Int32Array; // per vertex
  rows: number;
  cols: number;
  mass: Float64Array; // per bin
  keep: Uint8Array;
  dil: Uint8Array;
  label: Int32Array;
  stack: Int32Array;
  sorted: Float64Array;
  w: Float64Array; // per live vertex
}

const grids = new WeakMap<Float64Array, BinGrid>();

function binGrid(px: Float64Array, py: Float64Array, bin_m: number): BinGrid {
  const hit = grids.get(px);
  if (hit && hit.bin_m === bin_m && hit.bin.length === px.length) return hit;
  let lx = Infinity;
  let ly = Infinity;
  for (let v = 0; v < px.length; v++) {
    if (px[v] < lx) lx = px[v];
    if (py[v] < ly) ly = py[v];
  }
  const bx = new Int32Array(px.length);
  const by = new Int32Array(px.length);
  let cols = 0;
  let rows = 0;
  for (let v = 0; v < px.length; v++) {
    bx[v] = Math.floor((px[v] - lx) / bin_m);
    by[v] = Math.floor((py[v] - ly) / bin_m);
    if (bx[v] >= cols) cols = bx[v] + 1;
    if (by[v] >= rows) rows = by[v] + 1;
  }
  const bin = new Int32Array(px.length);
  for (let v = 0; v < px.length; v++) bin[v] = by[v] * cols + bx[v];
  const nb = rows * cols;
  const g = { bin_m, bin, rows, cols, mass: new Float64Array(nb), keep: new Uint8Array(nb), dil: new Uint8Array(nb), label: new Int32Array(nb), stack: new Int32Array(nb), sorted: new Float64Array(nb), w: new Float64Array(px.length) };
  grids.set(px, g);
  return g;
}

/**
 * Mark in `keep` the fewest bins holding `support` of the mass `m`, taken by mass descending
 * and, among equal masses, by bin index (np.searchsorted over the cumulative sum). The
 * cumulative sum runs over the masses in that order, so a native sort of the masses alone
 * finds where it crosses `support`; then the tied bins at the crossing are taken in index order.
 */
function supportBins(m: Float64Array, support: number, keep: Uint8Array, scratch: Float64Array): void {
  keep.fill(0);
  let nz = 0;
  for (let b = 0; b < m.length; b++) if (m[b] > 0) scratch[nz++] = m[b];
  const sorted = scratch.subarray(0, nz).sort();
  // Bins without mass come last in the order and are never needed: the mass sums to 1 > support.
  let cum = 0;
  let i = nz - 1;
  for (; i >= 0; i--) {
    cum += sorted[i];
    if (cum >= support) break;
  }
  const last = Math.max(i, 0);
  const cut = sorted[last];
  let ties = 1; // bins of mass `cut` taken: the one at the crossing and those after it in the order
  for (let j = last + 1; j < nz && sorted[j] === cut; j++) ties++;
  for (let b = 0; b < m.length; b++) {
    if (m[b] > cut) keep[b] = 1;
    else if (m[b] === cut && ties > 0) (keep[b] = 1), ties--;
  }
}

/** Components of `keep` dilated by one bin, 8-connected, labelled 1.. in raster order of their first cell (as scipy.ndimage.label). */
function labelDilated(g: BinGrid): number {
  const { keep, rows, cols, dil, label, stack } = g;
  dil.fill(0);
  label.fill(0);
  for (let r = 0; r < rows; r++) {
    for (let c = 0; c < cols; c++) {
      if (!keep[r * cols + c]) continue;
      for (let i = Math.max(r - 1, 0); i <= Math.min(r + 1, rows - 1); i++) for (let j = Math.max(c - 1, 0); j <= Math.min(c + 1, cols - 1); j++) dil[i * cols + j] = 1;
    }
  }
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
  return count;
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
  for (let i = 0; i < live.length; i++) total += weight[live[i]];
  if (!(total > 0)) throw new Error("posteriorModes: the distribution has no mass");
  const grid = binGrid(px, py, bin_m);
  const { bin, keep, label } = grid;
  const w = grid.w;
  const m = grid.mass.fill(0);
  for (let i = 0; i < live.length; i++) {
    const x = weight[live[i]] / total;
    w[i] = x;
    m[bin[live[i]]] += x;
  }
  supportBins(m, support, keep, grid.sorted);
  const count = labelDilated(grid);
  const mass = new Float64Array(count + 1);
  const sx = new Float64Array(count + 1);
  const sy = new Float64Array(count + 1);
  for (let i = 0; i < live.length; i++) {
    const v = live[i];
    const b = bin[v];
    const l = keep[b] ? label[b] : 0;
    mass[l] += w[i];
    sx[l] += w[i] * px[v];
    sy[l] += w[i] * py[v];
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
