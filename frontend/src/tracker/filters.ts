/**
 * The online recursions of `posefix.mapmatch.viterbi` over a model's grid, on typed arrays.
 * With pred[k][v] the vertex u such that v = u + o_k (-1: none), trans (K,) the step's
 * weighted transition scores and state (V,) its weighted state scores (or none):
 *
 *   Viterbi:  δ_t(v) = max_k δ_{t−1}(pred[k][v]) + trans[k] + state(v)      (back-pointer: the arg-max k)
 *   Forward:  α_t(v) = log Σ_k e^{α_{t−1}(pred[k][v]) + trans[k]} + state(v)  (kept as e^{α − max α})
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
  private liveBufs: [Int32Array, Int32Array];
  private readonly mark: Uint8Array;
  private readonly acc: Float64Array;
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
    this.liveBufs = [new Int32Array(n), new Int32Array(n)];
    let top = NEG;
    for (let v = 0; v < n; v++) if (logPrior[v] > top) top = logPrior[v];
    const thr = beam === null ? NEG : top - beam;
    let c = 0;
    const live = this.liveBufs[0];
    for (let v = 0; v < n; v++) {
      if (logPrior[v] > NEG && logPrior[v] >= thr) {
        this.lin[v] = Math.exp(logPrior[v] - top);
        live[c++] = v;
      }
    }
    this.live = live.subarray(0, c);
    this.mark = new Uint8Array(n);
    this.acc = new Float64Array(n);
  }

  step(trans: Float64Array, state: Float64Array | null): void {
    const { g } = this;
    const n = g.n;
    const k = g.k;
    const cand = candidates(g, { val: this.lin, live: this.live }, this.beam, this.mark);
    const a = this.lin;
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
    let best = 0;
    if (state) {
      // log domain: log(acc) + state, as the Python filter does it
      best = NEG;
      for (let i = 0; i < m; i++) {
        const x = Math.log(acc[i]) + state[cand ? cand[i] : i];
        acc[i] = x;
        if (x > best) best = x;
      }
      if (!(best > NEG)) return; // every path hit a wall: keep the belief
      for (let i = 0; i < m; i++) acc[i] = Math.exp(acc[i] - best);
    } else {
      for (let i = 0; i < m; i++) if (acc[i] > best) best = acc[i];
      if (!(best > 0)) return;
      for (let i = 0; i < m; i++) acc[i] /= best;
    }
    const out = this.next;
    const liveOut = this.liveBufs[this.live.buffer === this.liveBufs[0].buffer ? 1 : 0];
    let c = 0;
    for (let i = 0; i < m; i++) {
      const x = acc[i];
      if (x > 0 && x >= this.floor) {
        const v = cand ? cand[i] : i;
        out[v] = x;
        liveOut[c++] = v;
      }
    }
    for (const v of this.live) a[v] = 0;
    this.next = a;
    this.lin = out;
    this.live = liveOut.subarray(0, c);
  }

  /** The filtered marginal as probabilities on the live vertices (sum 1). */
  probabilities(): { p: Float64Array; live: Int32Array } {
    let s = 0;
    for (const v of this.live) s += this.lin[v];
    const p = new Float64Array(this.live.length);
    this.live.forEach((v, i) => (p[i] = this.lin[v] / s));
    return { p, live: this.live };
  }
}

/** Moment-matched Gaussian of a log column over the graph's vertices (see the module docstring). */
/**
 * Moment-matched Gaussian of a distribution over the graph's vertices, from weights on the
 * live vertices (any scale; entries under e^{−20} of the largest are left out).
 */
export function gaussianSummary(g: Graph, w: Float64Array, live: Int32Array, minSigma: number, cutNats = 20): Summary {
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
  cxx += minSigma * minSigma;
  cyy += minSigma * minSigma;
  const mean = (cxx + cyy) / 2;
  const r = Math.sqrt(((cxx - cyy) / 2) ** 2 + cxy * cxy);
  const angle = ((0.5 * Math.atan2(2 * cxy, cxx - cyy) * 180) / Math.PI + 180) % 180;
  return { x: mx, y: my, cxx, cxy, cyy, sigma_major_m: Math.sqrt(Math.max(mean + r, 0)), sigma_minor_m: Math.sqrt(Math.max(mean - r, 0)), angle_deg: angle };
}
