/**
 * The online recursions of `posefix.mapmatch.viterbi` over a model's grid, on typed arrays.
 * With pred[v, k] the vertex u such that v = u + o_k (none: −∞), trans (K,) the step's
 * weighted transition scores and state (V,) its weighted state scores (or none):
 *
 *   Viterbi:  δ_t(v) = max_k δ_{t−1}(pred[v, k]) + trans[k] + state(v)      (back-pointer: the arg-max k)
 *   Forward:  α_t(v) = log Σ_k e^{α_{t−1}(pred[v, k]) + trans[k]} + state(v)  (kept as e^{α − max α})
 *   Beam:     entries more than `beam` nats below the column's best are dropped (−∞)
 *
 * and the Gaussian summary of a distribution p (V,): w_v = p_v / Σp (entries within 20 nats
 * of the best), μ = Σ w_v p_v, Σ = Σ w_v (p_v − μ)(p_v − μ)ᵀ + σ_min² I, with its 1σ
 * semi-axes (eigenvalues) and the major axis' angle, counter-clockwise from east.
 */
import type { Graph } from "./model";

const NEG = -Infinity;

export interface Summary {
  x: number;
  y: number;
  cxx: number;
  cxy: number;
  cyy: number;
  sigma_major_m: number;
  sigma_minor_m: number;
  angle_deg: number;
}

/** A column over the vertices: dense values (−∞ off the beam) and the live vertices, ascending. */
export interface Column {
  val: Float64Array;
  live: Int32Array;
}

/** Whether the next step evaluates every vertex: no beam, or a third of the vertices or more live. */
export function denseStep(g: Graph, live: Int32Array, beam: number | null): boolean {
  return beam === null || live.length >= Math.trunc(g.n / 3);
}

/**
 * The vertices to evaluate for the next step, written to `out` (count returned): with a
 * beam and under a third of the vertices live, only those one transition away from a live
 * one; else −1 (all of them).
 */
export function candidates(g: Graph, live: Int32Array, beam: number | null, mark: Uint8Array, out: Int32Array): number {
  if (denseStep(g, live, beam)) return -1;
  const k = g.k;
  const succ = g.succ;
  let lo = g.n;
  let hi = -1;
  for (let i = 0; i < live.length; i++) {
    const base = live[i] * k;
    for (let j = 0; j < k; j++) {
      const v = succ[base + j];
      if (v >= 0 && !mark[v]) {
        mark[v] = 1;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
    }
  }
  let m = 0;
  for (let v = lo; v <= hi; v++) if (mark[v]) (out[m++] = v), (mark[v] = 0);
  return m;
}

/**
 * One column's storage: values with the sentinel entry n (always the neutral value) and
 * two live-index buffers used in turn, so a step allocates nothing of the graph's size.
 */
class LiveBuffers {
  private readonly bufs: [Int32Array, Int32Array];
  constructor(n: number) {
    this.bufs = [new Int32Array(n), new Int32Array(n)];
  }
  /** The buffer not holding `current`. */
  other(current: Int32Array): Int32Array {
    return current.buffer === this.bufs[0].buffer ? this.bufs[1] : this.bufs[0];
  }
}

export class ViterbiFilter {
  delta: Column;
  /** Back-pointers of the last `keep` steps (Int8: offset index, −1 unreachable), oldest first. */
  back: Int8Array[] = [];
  /** The best vertex of δ (the first in vertex order on ties, as np.argmax). */
  top = -1;
  private readonly mark: Uint8Array;
  private readonly cand: Int32Array;
  private readonly lives: LiveBuffers;
  private spare: Float64Array;

  constructor(
    readonly g: Graph,
    logPrior: Float64Array,
    readonly beam: number | null,
    readonly keep: number,
  ) {
    if (logPrior.length !== g.n) throw new Error(`log prior has ${logPrior.length} entries, the graph ${g.n} vertices`);
    if (!logPrior.some((v) => v > NEG)) throw new Error("the start prior has no possible vertex");
    const n = g.n;
    // One entry more than the vertices: index n is the "no predecessor" sentinel, always −∞.
    const first = new Float64Array(n + 1).fill(NEG);
    this.spare = new Float64Array(n + 1).fill(NEG);
    this.lives = new LiveBuffers(n);
    this.mark = new Uint8Array(n);
    this.cand = new Int32Array(n);
    let best = NEG;
    for (let v = 0; v < n; v++) {
      first[v] = logPrior[v];
      if (logPrior[v] > best) (best = logPrior[v]), (this.top = v);
    }
    this.delta = this.prune(first, null, n, best, this.lives.other(new Int32Array(0)));
  }

  /** Drop the entries of `val` (over `idx`, or all) more than `beam` below `best`; their live list. */
  private prune(val: Float64Array, idx: Int32Array | null, m: number, best: number, liveBuf: Int32Array): Column {
    const thr = this.beam === null ? NEG : best - this.beam;
    let c = 0;
    for (let i = 0; i < m; i++) {
      const v = idx ? idx[i] : i;
      const x = val[v];
      if (x >= thr && x > NEG) liveBuf[c++] = v;
      else val[v] = NEG;
    }
    return { val, live: liveBuf.subarray(0, c) };
  }

  private backArray(): Int8Array {
    const b = this.back.length >= this.keep ? this.back.shift()! : new Int8Array(this.g.n);
    return b.fill(-1);
  }

  /** The vertices the next step evaluates, in `this.cand` (count), or −1: all of them. */
  plan(): number {
    return candidates(this.g, this.delta.live, this.beam, this.mark, this.cand);
  }

  step(trans: Float64Array, state: Float64Array | null): void {
    const { g } = this;
    const k = g.k;
    const m = this.plan();
    const cand = m >= 0 ? this.cand : null;
    const count = m >= 0 ? m : g.n;
    const d = this.delta.val;
    const pv = g.predV;
    const out = this.spare;
    const back = this.backArray();
    const t0 = trans[0];
    let best = NEG;
    let top = -1;
    // Vertex by vertex over its K predecessors (one row of predV): the running maximum stays
    // in a register. Ties keep the lower offset, as numpy's strict `greater` does.
    for (let i = 0; i < count; i++) {
      const v = cand ? cand[i] : i;
      const row = v * k;
      let b = d[pv[row]] + t0;
      let kb = 0;
      for (let j = 1; j < k; j++) {
        const c = d[pv[row + j]] + trans[j];
        if (c > b) (b = c), (kb = j);
      }
      if (b > NEG) back[v] = kb;
      if (state) b += state[v];
      out[v] = b;
      if (b > best) (best = b), (top = v);
    }
    this.finish(back, cand, count, best, top);
  }

  /** Buffers for a step over every vertex computed elsewhere (stepDense): δ, the next δ's and the back-pointers. */
  denseBuffers(): { d: Float64Array; out: Float64Array; back: Int8Array } {
    return { d: this.delta.val, out: this.spare, back: this.backArray() };
  }

  /** After the relaxation wrote `this.spare` and `back` over the candidates: prune, or keep the belief at a wall. */
  finish(back: Int8Array, cand: Int32Array | null, count: number, best: number, top: number): void {
    const out = this.spare;
    if (best > NEG) {
      const old = this.delta;
      const d = old.val;
      this.delta = this.prune(out, cand, count, best, this.lives.other(old.live));
      this.top = top;
      for (let i = 0; i < old.live.length; i++) d[old.live[i]] = NEG;
      this.spare = d;
    } else {
      // Every path hit a wall: keep the belief (the walker is taken to have stood still).
      for (let i = 0; i < count; i++) out[cand ? cand[i] : i] = NEG;
      back.fill(-1);
      for (const v of this.delta.live) back[v] = 0;
    }
    this.back.push(back);
  }

  /** The last `lastN + 1` vertices of the most likely path (lastN ≤ the kept steps). */
  bestPath(lastN: number): Int32Array {
    let v = this.top;
    const t = this.back.length;
    const n = Math.min(lastN, t);
    const out = new Int32Array(n + 1);
    out[n] = v;
    for (let i = 0; i < n; i++) {
      const kk = this.back[t - 1 - i][v];
      if (kk < 0) throw new Error("back-pointer chain broken (pruned state on the best path)");
      v = this.g.predV[v * this.g.k + kk];
      out[n - 1 - i] = v;
    }
    return out;
  }
}

/**
 * The forward filter kept in the linear domain, scaled so that its largest entry is 1:
 * lin = e^{α − max α}. A step without state scores needs no exponential or logarithm
 * (the transition maximum cancels in the scaling); with state scores the row goes
 * through the log domain as in Python, so a far WiFi fix cannot underflow every entry.
 */
export class ForwardFilter {
  lin: Float64Array; // [n] = 0: the sentinel
  live: Int32Array;
  private next: Float64Array;
  private readonly lives: LiveBuffers;
  private readonly mark: Uint8Array;
  private readonly cand: Int32Array;
  private readonly acc: Float64Array;
  private readonly e: Float64Array;
  private readonly floor: number;

  constructor(
    readonly g: Graph,
    logPrior: Float64Array,
    readonly beam: number | null,
  ) {
    const n = g.n;
    this.floor = beam === null ? 0 : Math.exp(-beam);
    this.lin = new Float64Array(n + 1);
    this.next = new Float64Array(n + 1);
    this.lives = new LiveBuffers(n);
    let top = NEG;
    for (let v = 0; v < n; v++) if (logPrior[v] > top) top = logPrior[v];
    const thr = beam === null ? NEG : top - beam;
    let c = 0;
    const live = this.lives.other(new Int32Array(0));
    for (let v = 0; v < n; v++) {
      if (logPrior[v] > NEG && logPrior[v] >= thr) {
        this.lin[v] = Math.exp(logPrior[v] - top);
        live[c++] = v;
      }
    }
    this.live = live.subarray(0, c);
    this.mark = new Uint8Array(n);
    this.cand = new Int32Array(n);
    this.acc = new Float64Array(n);
    this.e = new Float64Array(g.k);
  }

  /** The vertices the next step evaluates, in `this.cand` (count), or −1: all of them. */
  plan(): number {
    return candidates(this.g, this.live, this.beam, this.mark, this.cand);
  }

  /** e^{trans − max trans} (K,): the step's transition factors, scaled so the largest is 1. */
  factors(trans: Float64Array): Float64Array {
    let tTop = NEG;
    for (let j = 0; j < trans.length; j++) if (trans[j] > tTop) tTop = trans[j];
    const e = this.e;
    for (let j = 0; j < trans.length; j++) {
      const tk = trans[j] - tTop;
      e[j] = tk > -300 ? Math.exp(tk) : 0;
    }
    return e;
  }

  step(trans: Float64Array, state: Float64Array | null): void {
    const { g } = this;
    const k = g.k;
    const m = this.plan();
    const cand = m >= 0 ? this.cand : null;
    const count = m >= 0 ? m : g.n;
    const a = this.lin;
    const e = this.factors(trans);
    const pv = g.predV;
    const acc = this.acc;
    const e0 = e[0];
    // Vertex by vertex, offsets in order (the sum's order is numpy's: offset 0 first; a
    // term with e = 0 adds an exact 0, where numpy skips it).
    let best = 0;
    for (let i = 0; i < count; i++) {
      const row = (cand ? cand[i] : i) * k;
      let s = a[pv[row]] * e0;
      for (let j = 1; j < k; j++) s += a[pv[row + j]] * e[j];
      acc[i] = s;
      if (s > best) best = s;
    }
    this.finish(cand, count, best, state);
  }

  /** After `this.acc` holds the sums over the candidates (and `best` their largest): state scores, scale, prune. */
  finish(cand: Int32Array | null, count: number, best: number, state: Float64Array | null): void {
    const acc = this.acc;
    const a = this.lin;
    if (state) {
      // log domain: log(acc) + state, as the Python filter does it
      best = NEG;
      for (let i = 0; i < count; i++) {
        const x = Math.log(acc[i]) + state[cand ? cand[i] : i];
        acc[i] = x;
        if (x > best) best = x;
      }
      if (!(best > NEG)) return; // every path hit a wall: keep the belief
      for (let i = 0; i < count; i++) acc[i] = Math.exp(acc[i] - best);
      best = 1;
    } else if (!(best > 0)) return;
    const out = this.next;
    const liveOut = this.lives.other(this.live);
    const floor = this.floor * best;
    let c = 0;
    for (let i = 0; i < count; i++) {
      const x = acc[i];
      if (x > 0 && x >= floor) {
        const v = cand ? cand[i] : i;
        out[v] = x / best;
        liveOut[c++] = v;
      }
    }
    for (let i = 0; i < this.live.length; i++) a[this.live[i]] = 0;
    this.next = a;
    this.lin = out;
    this.live = liveOut.subarray(0, c);
  }

  /** The sums of a step computed elsewhere (stepDense) go here, one per vertex. */
  get sums(): Float64Array {
    return this.acc;
  }
}

/**
 * One step of both filters. When both evaluate every vertex (an unknown start: most of the
 * floor live), one pass reads each vertex's predecessor row once for both; otherwise each
 * filter steps alone. The results are those of `viterbi.step` and `forward.step`.
 */
export function stepFilters(viterbi: ViterbiFilter, forward: ForwardFilter, trans: Float64Array, state: Float64Array | null): void {
  if (!denseStep(viterbi.g, viterbi.delta.live, viterbi.beam) || !denseStep(forward.g, forward.live, forward.beam)) {
    viterbi.step(trans, state);
    forward.step(trans, state);
    return;
  }
  const g = viterbi.g;
  const n = g.n;
  const k = g.k;
  const pv = g.predV;
  const { d, out, back } = viterbi.denseBuffers();
  const a = forward.lin;
  const e = forward.factors(trans);
  const acc = forward.sums;
  const t0 = trans[0];
  const e0 = e[0];
  let best = NEG;
  let top = -1;
  let sBest = 0;
  for (let v = 0; v < n; v++) {
    const row = v * k;
    let u = pv[row];
    let b = d[u] + t0;
    let s = a[u] * e0;
    let kb = 0;
    for (let j = 1; j < k; j++) {
      u = pv[row + j];
      const c = d[u] + trans[j];
      if (c > b) (b = c), (kb = j);
      s += a[u] * e[j];
    }
    if (b > NEG) back[v] = kb;
    if (state) b += state[v];
    out[v] = b;
    if (b > best) (best = b), (top = v);
    acc[v] = s;
    if (s > sBest) sBest = s;
  }
  viterbi.finish(back, null, n, best, top);
  forward.finish(null, n, sBest, state);
}

/** Moment-matched Gaussian of a log column over the graph's vertices (see the module docstring). */
/**
 * Moment-matched Gaussian of a distribution over the graph's vertices, from weights on the
 * live vertices (any scale; entries under e^{−20} of the largest are left out).
 */
export function gaussianSummary(g: Graph, w: Float64Array, live: Int32Array, minSigma: number, cutNats = 20, covScale = 1): Summary {
  const m = live.length;
  let top = 0;
  for (let i = 0; i < m; i++) if (w[live[i]] > top) top = w[live[i]];
  const thr = top * Math.exp(-cutNats);
  let s = 0;
  let sx = 0;
  let sy = 0;
  for (let i = 0; i < m; i++) {
    const v = live[i];
    const x = w[v];
    if (!(x > thr)) continue;
    s += x;
    sx += x * g.px[v];
    sy += x * g.py[v];
  }
  const mx = sx / s;
  const my = sy / s;
  let cxx = 0;
  let cxy = 0;
  let cyy = 0;
  for (let i = 0; i < m; i++) {
    const v = live[i];
    if (!(w[v] > thr)) continue;
    const x = w[v] / s;
    const dx = g.px[v] - mx;
    const dy = g.py[v] - my;
    cxx += dx * x * dx;
    cxy += dx * x * dy;
    cyy += dy * x * dy;
  }
  // The floor, then the model file's ellipse_scale (1 unless an older file kept one).
  cxx = (cxx + minSigma * minSigma) * covScale;
  cyy = (cyy + minSigma * minSigma) * covScale;
  cxy *= covScale;
  const mean = (cxx + cyy) / 2;
  const r = Math.sqrt(((cxx - cyy) / 2) ** 2 + cxy * cxy);
  const angle = ((0.5 * Math.atan2(2 * cxy, cxx - cyy) * 180) / Math.PI + 180) % 180;
  return { x: mx, y: my, cxx, cxy, cyy, sigma_major_m: Math.sqrt(Math.max(mean + r, 0)), sigma_minor_m: Math.sqrt(Math.max(mean - r, 0)), angle_deg: angle };
}
