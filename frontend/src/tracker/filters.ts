/**
 * The online recursions of `posefix.mapmatch.viterbi` over a model's grid, on typed arrays.
 * With pred[k][v] the vertex u such that v = u + o_k (-1: none), trans (K,) the step's
 * weighted transition scores and state (V,) its weighted state scores (or none):
 *
 *   Viterbi:  δ_t(v) = max_k δ_{t−1}(pred[k][v]) + trans[k] + state(v)      (back-pointer: the arg-max k)
 *   Forward:  α_t(v) = log Σ_k e^{α_{t−1}(pred[k][v]) + trans[k]} + state(v)  (linear domain, scaled by the maxima)
 *   Beam:     entries more than `beam` nats below the column's best are dropped (−∞)
 *
 * and the Gaussian summary of a column log p (V,): w_v = p_v / Σp (entries within 20 nats
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

export function argmax(c: Column): number {
  let m = NEG;
  let j = 0;
  for (const v of c.live) if (c.val[v] > m) (m = c.val[v]), (j = v);
  return j;
}

/** The column with entries more than `beam` nats below the best dropped, from the vertices `idx` (ascending). */
function pruned(val: Float64Array, idx: Int32Array | null, n: number, beam: number | null): Column {
  const m = idx ? idx.length : n;
  let top = NEG;
  for (let i = 0; i < m; i++) {
    const x = val[idx ? idx[i] : i];
    if (x > top) top = x;
  }
  const thr = beam === null ? NEG : top - beam;
  const live = new Int32Array(m);
  let c = 0;
  for (let i = 0; i < m; i++) {
    const v = idx ? idx[i] : i;
    if (val[v] >= thr && val[v] > NEG) live[c++] = v;
    else val[v] = NEG;
  }
  return { val, live: live.slice(0, c) };
}

/**
 * The vertices to evaluate for the next step: with a beam and under a third of the
 * vertices live, only those one transition away from a live one; else all (null).
 */
export function candidates(g: Graph, c: Column, beam: number | null, mark: Uint8Array): Int32Array | null {
  if (beam === null || c.live.length >= Math.trunc(g.n / 3)) return null;
  const k = g.k;
  let m = 0;
  for (const u of c.live) {
    for (let j = 0; j < k; j++) {
      const v = g.succ[u * k + j];
      if (v >= 0 && !mark[v]) (mark[v] = 1), m++;
    }
  }
  const out = new Int32Array(m);
  for (let v = 0, i = 0; i < m; v++) if (mark[v]) (out[i++] = v), (mark[v] = 0);
  return out;
}

/** Two column buffers used in turn, so a step allocates nothing of the graph's size. */
class PingPong {
  private bufs: [Float64Array, Float64Array];
  private i = 0;
  constructor(n: number) {
    // One entry more than the vertices: index n is the "no predecessor" sentinel, always −∞.
    this.bufs = [new Float64Array(n + 1).fill(NEG), new Float64Array(n + 1).fill(NEG)];
  }
  /** The buffer not holding `current` (all −∞). */
  next(current: Column): Float64Array {
    const b = this.bufs[this.i];
    return b === current.val ? this.bufs[1 - this.i] : b;
  }
  /** `old` is no longer needed: reset its live entries so it can be the next buffer. */
  release(old: Column, now: Column): void {
    if (old.val === now.val) return;
    for (const v of old.live) old.val[v] = NEG;
    this.i = this.bufs[0] === old.val ? 0 : 1;
  }
}

export class ViterbiFilter {
  delta: Column;
  /** Back-pointers of the last `keep` steps (Int8: offset index, −1 unreachable), oldest first. */
  back: Int8Array[] = [];
  private readonly mark: Uint8Array;
  private readonly bufs: PingPong;
  private readonly best: Float64Array;
  private readonly kb: Int8Array;

  constructor(
    readonly g: Graph,
    logPrior: Float64Array,
    readonly beam: number | null,
    readonly keep: number,
  ) {
    if (logPrior.length !== g.n) throw new Error(`log prior has ${logPrior.length} entries, the graph ${g.n} vertices`);
    if (!logPrior.some((v) => v > NEG)) throw new Error("the start prior has no possible vertex");
    this.bufs = new PingPong(g.n);
    const first = this.bufs.next({ val: new Float64Array(0), live: new Int32Array(0) });
    first.set(logPrior);
    this.delta = pruned(first, null, g.n, beam);
    this.mark = new Uint8Array(g.n);
    this.best = new Float64Array(g.n);
    this.kb = new Int8Array(g.n);
  }

  private backArray(): Int8Array {
    const b = this.back.length >= this.keep ? this.back.shift()! : new Int8Array(this.g.n);
    return b.fill(-1);
  }

  step(trans: Float64Array, state: Float64Array | null): void {
    const { g } = this;
    const n = g.n;
    const k = g.k;
    const cand = candidates(g, this.delta, this.beam, this.mark);
    const d = this.delta.val;
    const m = cand ? cand.length : n;
    const pt = g.predS;
    const best = this.best;
    const kb = this.kb;
    // One offset at a time over the candidates (contiguous reads of pred[k]), as numpy does;
    // pred = n (the sentinel) reads −∞.
    if (cand) {
      for (let i = 0; i < m; i++) (best[i] = d[pt[cand[i]]] + trans[0]), (kb[i] = 0);
      for (let j = 1; j < k; j++) {
        const row = j * n;
        const tj = trans[j];
        for (let i = 0; i < m; i++) {
          const c = d[pt[row + cand[i]]] + tj;
          if (c > best[i]) (best[i] = c), (kb[i] = j);
        }
      }
    } else {
      for (let i = 0; i < n; i++) (best[i] = d[pt[i]] + trans[0]), (kb[i] = 0);
      for (let j = 1; j < k; j++) {
        const row = j * n;
        const tj = trans[j];
        for (let i = 0; i < n; i++) {
          const c = d[pt[row + i]] + tj;
          if (c > best[i]) (best[i] = c), (kb[i] = j);
        }
      }
    }
    const out = this.bufs.next(this.delta);
    const back = this.backArray();
    let any = false;
    for (let i = 0; i < m; i++) {
      const v = cand ? cand[i] : i;
      let b = best[i];
      if (b > NEG) back[v] = kb[i];
      if (state) b += state[v];
      out[v] = b;
      if (b > NEG) any = true;
    }
    if (any) {
      const old = this.delta;
      this.delta = pruned(out, cand, n, this.beam);
      this.bufs.release(old, this.delta);
    } else {
      // Every path hit a wall: keep the belief (the walker is taken to have stood still).
      for (let i = 0; i < m; i++) out[cand ? cand[i] : i] = NEG;
      back.fill(-1);
      for (const v of this.delta.live) back[v] = 0;
    }
    this.back.push(back);
  }

  /** The last `lastN + 1` vertices of the most likely path (lastN ≤ the kept steps). */
  bestPath(lastN: number): Int32Array {
    let v = argmax(this.delta);
    const t = this.back.length;
    const n = Math.min(lastN, t);
    const out = new Int32Array(n + 1);
    out[n] = v;
    for (let i = 0; i < n; i++) {
      const kk = this.back[t - 1 - i][v];
      if (kk < 0) throw new Error("back-pointer chain broken (pruned state on the best path)");
      v = this.g.predT[kk * this.g.n + v];
      out[n - 1 - i] = v;
    }
    return out;
  }
}

export class ForwardFilter {
  alpha: Column;
  private readonly mark: Uint8Array;
  private readonly lin: Float64Array; // e^{α − top} on the live vertices, 0 elsewhere
  private readonly acc: Float64Array;
  private readonly bufs: PingPong;
  private readonly norm: Float64Array;

  constructor(
    readonly g: Graph,
    logPrior: Float64Array,
    readonly beam: number | null,
  ) {
    this.bufs = new PingPong(g.n);
    const first = this.bufs.next({ val: new Float64Array(0), live: new Int32Array(0) });
    first.set(logPrior);
    this.alpha = pruned(first, null, g.n, beam);
    this.mark = new Uint8Array(g.n);
    this.lin = new Float64Array(g.n + 1); // [n] = 0: the sentinel
    this.acc = new Float64Array(g.n);
    this.norm = new Float64Array(g.n + 1);
  }

  step(trans: Float64Array, state: Float64Array | null): void {
    const { g } = this;
    const n = g.n;
    const k = g.k;
    const cand = candidates(g, this.alpha, this.beam, this.mark);
    const al = this.alpha;
    let top = NEG;
    for (const v of al.live) if (al.val[v] > top) top = al.val[v];
    const a = this.lin;
    for (const v of al.live) a[v] = Math.exp(al.val[v] - top);
    let tTop = NEG;
    for (let j = 0; j < k; j++) if (trans[j] > tTop) tTop = trans[j];
    const e = new Float64Array(k);
    for (let j = 0; j < k; j++) {
      const tk = trans[j] - tTop;
      e[j] = tk > -300 ? Math.exp(tk) : 0;
    }
    const m = cand ? cand.length : n;
    const pt = g.predS;
    const acc = this.acc;
    if (cand) {
      for (let i = 0; i < m; i++) acc[i] = a[pt[cand[i]]] * e[0];
      for (let j = 1; j < k; j++) {
        const ej = e[j];
        if (ej === 0) continue;
        const row = j * n;
        for (let i = 0; i < m; i++) acc[i] += a[pt[row + cand[i]]] * ej;
      }
    } else {
      for (let i = 0; i < n; i++) acc[i] = a[pt[i]] * e[0];
      for (let j = 1; j < k; j++) {
        const ej = e[j];
        if (ej === 0) continue;
        const row = j * n;
        for (let i = 0; i < n; i++) acc[i] += a[pt[row + i]] * ej;
      }
    }
    const off = top + tTop;
    const out = this.bufs.next(al);
    let best = NEG;
    for (let i = 0; i < m; i++) {
      const v = cand ? cand[i] : i;
      let x = Math.log(acc[i]) + off;
      if (state) x += state[v];
      out[v] = x;
      if (x > best) best = x;
    }
    for (const v of al.live) a[v] = 0;
    if (!(best > NEG)) {
      for (let i = 0; i < m; i++) out[cand ? cand[i] : i] = NEG;
      return; // every path hit a wall: keep the belief
    }
    for (let i = 0; i < m; i++) out[cand ? cand[i] : i] -= best;
    this.alpha = pruned(out, cand, n, this.beam);
    this.bufs.release(al, this.alpha);
  }

  /** The filtered marginal, log-normalised (valid on its live vertices only; read it before the next step). */
  column(): Column {
    const c = this.alpha;
    let top = NEG;
    for (const v of c.live) if (c.val[v] > top) top = c.val[v];
    let s = 0;
    for (const v of c.live) s += Math.exp(c.val[v] - top);
    const kk = top + Math.log(s);
    for (const v of c.live) this.norm[v] = c.val[v] - kk;
    return { val: this.norm, live: c.live };
  }
}

/** Moment-matched Gaussian of a log column over the graph's vertices (see the module docstring). */
export function gaussianSummary(g: Graph, c: Column, minSigma: number, cutNats = 20): Summary {
  let top = NEG;
  for (const v of c.live) if (c.val[v] > top) top = c.val[v];
  const thr = top - cutNats;
  const sel = c.live.filter((v) => c.val[v] > thr);
  const w = new Float64Array(sel.length);
  let s = 0;
  sel.forEach((v, i) => (s += w[i] = Math.exp(c.val[v] - top)));
  let mx = 0;
  let my = 0;
  for (let i = 0; i < sel.length; i++) {
    w[i] /= s;
    mx += w[i] * g.px[sel[i]];
    my += w[i] * g.py[sel[i]];
  }
  let cxx = 0;
  let cxy = 0;
  let cyy = 0;
  for (let i = 0; i < sel.length; i++) {
    const dx = g.px[sel[i]] - mx;
    const dy = g.py[sel[i]] - my;
    cxx += dx * w[i] * dx;
    cxy += dx * w[i] * dy;
    cyy += dy * w[i] * dy;
  }
  cxx += minSigma * minSigma;
  cyy += minSigma * minSigma;
  const mean = (cxx + cyy) / 2;
  const r = Math.sqrt(((cxx - cyy) / 2) ** 2 + cxy * cxy);
  const angle = ((0.5 * Math.atan2(2 * cxy, cxx - cyy) * 180) / Math.PI + 180) % 180;
  return { x: mx, y: my, cxx, cxy, cyy, sigma_major_m: Math.sqrt(Math.max(mean + r, 0)), sigma_minor_m: Math.sqrt(Math.max(mean - r, 0)), angle_deg: angle };
}
