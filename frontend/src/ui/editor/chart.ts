/**
 * Correction magnitude (m) along the run, drawn on a canvas: the current (preview) correction
 * as a filled profile, the loaded revision's as a faint line, the loaded revision's predicted
 * 1-sigma as a band about the current profile, the selection as a cursor.
 * Clicking picks the keyframe under the pointer.
 */
export interface ChartData {
  now: number[];
  before: number[];
  selected: number | null;
  deleted: boolean[];
  /** Per-keyframe horizontal 1-sigma (m), null where none was predicted. */
  sigma?: (number | null)[];
}

export class CorrectionChart {
  readonly canvas: HTMLCanvasElement;
  private data: ChartData = { now: [], before: [], selected: null, deleted: [] };

  constructor(onPick: (index: number) => void) {
    this.canvas = document.createElement("canvas");
    this.canvas.className = "chart";
    this.canvas.setAttribute("role", "img");
    this.canvas.setAttribute("aria-label", "Correction magnitude along the run");
    this.canvas.addEventListener("click", (e) => {
      const n = this.data.now.length;
      if (!n) return;
      const r = this.canvas.getBoundingClientRect();
      const x = (e.clientX - r.left - PAD_L) / Math.max(1, r.width - PAD_L - PAD_R);
      onPick(Math.max(0, Math.min(n - 1, Math.round(x * (n - 1)))));
    });
    new ResizeObserver(() => this.draw()).observe(this.canvas);
  }

  set(data: ChartData): void {
    this.data = data;
    this.draw();
  }

  draw(): void {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = c.clientWidth, hgt = c.clientHeight;
    if (!w || !hgt) return;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(hgt * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(hgt * dpr);
    }
    const g = c.getContext("2d");
    if (!g) return;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, hgt);
    const { now, before, selected } = this.data;
    const n = now.length;
    const sigma = this.data.sigma && this.data.sigma.length === n && this.data.sigma.some((v) => v !== null) ? this.data.sigma : null;
    this.canvas.dataset.band = sigma ? "1sigma" : "";
    const upper = sigma ? now.map((m, i) => m + (sigma[i] ?? 0)) : [];
    const maxM = Math.max(1, ...now, ...before, ...upper);
    const top = niceCeil(maxM);
    const pw = w - PAD_L - PAD_R, ph = hgt - PAD_T - PAD_B;
    const x = (i: number) => PAD_L + (n <= 1 ? 0 : (i / (n - 1)) * pw);
    const y = (m: number) => PAD_T + ph - (m / top) * ph;
    g.font = "11px system-ui, sans-serif";
    g.fillStyle = "#475569";
    g.strokeStyle = "#e2e8f0";
    g.lineWidth = 1;
    for (const f of [0, 0.5, 1]) {
      const yy = y(top * f);
      g.beginPath(); g.moveTo(PAD_L, yy); g.lineTo(w - PAD_R, yy); g.stroke();
      g.fillText(`${fmt(top * f)} m`, 2, yy + 4);
    }
    if (n === 0) return;
    // Decimate to at most 2 samples per pixel column (max per column keeps peaks visible).
    const cols = Math.max(1, Math.floor(pw));
    const profile = (vals: number[]) => {
      const out: [number, number][] = [];
      const per = Math.max(1, vals.length / cols);
      for (let s = 0; s < vals.length; s += per) {
        let m = 0;
        for (let i = Math.floor(s); i < Math.min(vals.length, Math.floor(s + per)); i++) m = Math.max(m, vals[i]);
        out.push([x(Math.floor(s)), y(m)]);
      }
      return out;
    };
    if (before.length === n) {
      g.strokeStyle = "rgba(15,23,42,0.35)";
      g.beginPath();
      profile(before).forEach(([px, py], i) => (i ? g.lineTo(px, py) : g.moveTo(px, py)));
      g.stroke();
    }
    if (sigma) {
      // the band about the current profile: |correction| +- 1 sigma, floored at zero
      const hi = profile(upper), lo = profile(now.map((m, i) => Math.max(0, m - (sigma[i] ?? 0))));
      g.fillStyle = "rgba(245,158,11,0.25)";
      g.beginPath();
      hi.forEach(([px, py], i) => (i ? g.lineTo(px, py) : g.moveTo(px, py)));
      for (let i = lo.length - 1; i >= 0; i--) g.lineTo(lo[i][0], lo[i][1]);
      g.closePath();
      g.fill();
    }
    const p = profile(now);
    g.fillStyle = "rgba(37,99,235,0.25)";
    g.strokeStyle = "#2563eb";
    g.beginPath();
    g.moveTo(p[0][0], y(0));
    for (const [px, py] of p) g.lineTo(px, py);
    g.lineTo(p[p.length - 1][0], y(0));
    g.closePath();
    g.fill();
    g.beginPath();
    p.forEach(([px, py], i) => (i ? g.lineTo(px, py) : g.moveTo(px, py)));
    g.stroke();
    if (selected !== null && selected < n) {
      g.strokeStyle = "#0ea5e9";
      g.lineWidth = 2;
      g.beginPath(); g.moveTo(x(selected), PAD_T); g.lineTo(x(selected), PAD_T + ph); g.stroke();
      g.fillStyle = "#0f172a";
      const sd = sigma?.[selected];
      g.fillText(`#${selected}: ${fmt(now[selected])}${sd != null ? ` ± ${fmt(sd)}` : ""} m`, Math.min(x(selected) + 4, w - 110), PAD_T + 10);
    }
  }
}

const PAD_L = 44, PAD_R = 8, PAD_T = 6, PAD_B = 6;

function niceCeil(v: number): number {
  const p = Math.pow(10, Math.floor(Math.log10(v)));
  for (const m of [1, 2, 5, 10]) if (m * p >= v) return m * p;
  return 10 * p;
}

function fmt(m: number): string {
  return m >= 10 ? m.toFixed(0) : m.toFixed(1);
}
