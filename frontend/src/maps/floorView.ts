/**
 * Pure geometry of the floor view: floor metres (x east, y north, origin at the floor's
 * south-west corner) <-> canvas pixels (y down) and <-> lon/lat (the map view), and the
 * replay's derived values. No DOM.
 */
import type { FloorPlan, WalkStep, WalkTrack, WaypointError } from "./api";

export interface View {
  scale: number; // px per metre
  ox: number;
  oy: number;
  heightPx: number;
}

/** Fit a `width_m` x `height_m` floor into `w` x `h` px with `pad` px margins. */
export function fitView(width_m: number, height_m: number, w: number, h: number, pad = 10): View {
  return fitBox([0, 0, width_m, height_m], w, h, pad);
}

/** Fit the box [x0, y0, x1, y1] (metres) into `w` x `h` px, centred, keeping the aspect. */
export function fitBox(box: readonly [number, number, number, number], w: number, h: number, pad = 10): View {
  const [x0, y0, x1, y1] = box;
  const bw = Math.max(x1 - x0, 1e-6);
  const bh = Math.max(y1 - y0, 1e-6);
  const scale = Math.min((w - 2 * pad) / bw, (h - 2 * pad) / bh);
  return { scale, ox: (w - bw * scale) / 2 - x0 * scale, oy: (h - bh * scale) / 2 - y0 * scale, heightPx: h };
}

/** Bounding box of a walk (matched, dead reckoning, waypoints) with a margin (m), at least `minSide_m` a side. */
export function walkBox(track: WalkTrack, margin_m = 8, minSide_m = 30): [number, number, number, number] {
  const xs: number[] = [];
  const ys: number[] = [];
  for (const s of track.steps) for (const [x, y] of [[s.x_m, s.y_m], [s.dr_x_m, s.dr_y_m]]) if (Number.isFinite(x) && Number.isFinite(y)) xs.push(x), ys.push(y);
  for (const w of track.errors.waypoints) xs.push(w.x_m), ys.push(w.y_m);
  let [x0, x1, y0, y1] = [Math.min(...xs) - margin_m, Math.max(...xs) + margin_m, Math.min(...ys) - margin_m, Math.max(...ys) + margin_m];
  const grow = (lo: number, hi: number): [number, number] => {
    const d = Math.max(0, minSide_m - (hi - lo)) / 2;
    return [lo - d, hi + d];
  };
  [x0, x1] = grow(x0, x1);
  [y0, y1] = grow(y0, y1);
  return [x0, y0, x1, y1];
}

export function toPx(v: View, x: number, y: number): [number, number] {
  return [v.ox + x * v.scale, v.heightPx - (v.oy + y * v.scale)];
}

/** Canvas pixels -> floor metres (the inverse of toPx). */
export function fromPx(v: View, px: number, py: number): [number, number] {
  return [(px - v.ox) / v.scale, (v.heightPx - py - v.oy) / v.scale];
}

/** "x,y" in metres -> [x, y], or null (empty or not two finite numbers). */
export function parseStart(text: string): [number, number] | null {
  const p = text.split(",").map((s) => s.trim());
  if (p.length !== 2 || p.some((s) => !s)) return null;
  const [x, y] = p.map(Number);
  return Number.isFinite(x) && Number.isFinite(y) ? [x, y] : null;
}

/** The 2σ error ellipse in pixels: semi-axes and rotation (canvas radians, clockwise). */
export function ellipsePx(v: View, s: WalkStep, k = 2): { rx: number; ry: number; rotation: number } {
  return { rx: Math.max(k * s.sigma_major_m * v.scale, 1), ry: Math.max(k * s.sigma_minor_m * v.scale, 1), rotation: (-s.angle_deg * Math.PI) / 180 };
}

/** Waypoints reached by step `i` (time at or before that step's time; all of them at the last step, since the walk is over). */
export function reachedWaypoints(track: WalkTrack, i: number): WaypointError[] {
  if (i >= track.steps.length - 1) return track.errors.waypoints;
  const t = track.steps[Math.max(i, 0)]?.t_ms ?? -Infinity;
  return track.errors.waypoints.filter((w) => w.t_ms <= t);
}

export function fmtM(v: number | null | undefined): string {
  return v === null || v === undefined || !Number.isFinite(v) ? "–" : `${v.toFixed(2)} m`;
}

const M_PER_DEG = 111_320;

/** Floor metres (x east, y north from the floor's south-west corner) to [lon, lat]. */
export function floorLonLat(fp: Pick<FloorPlan, "georef">, x_m: number, y_m: number): [number, number] {
  const g = fp.georef;
  // Without a georeference the floor keeps its own frame: a metre is 1/111,320 degree near (0, 0).
  if (!g || g.length !== 4) return [x_m / M_PER_DEG, y_m / M_PER_DEG];
  return [g[0] + x_m * g[2], g[1] + y_m * g[3]];
}

/** The floor's corners, top-left first and clockwise (MapLibre's image source order). */
type LonLat = [number, number];

export function floorCorners(fp: Pick<FloorPlan, "georef" | "width_m" | "height_m">): [LonLat, LonLat, LonLat, LonLat] {
  const { width_m: w, height_m: hh } = fp;
  return [floorLonLat(fp, 0, hh), floorLonLat(fp, w, hh), floorLonLat(fp, w, 0), floorLonLat(fp, 0, 0)];
}

type Line = GeoJSON.Feature<GeoJSON.LineString | GeoJSON.Point | GeoJSON.Polygon, { kind: string }>;

/** What to draw of a walk up to step `n`. */
export function walkFeatures(fp: Pick<FloorPlan, "georef">, track: WalkTrack | null, n: number): GeoJSON.FeatureCollection {
  const features: Line[] = [];
  if (track && track.steps.length) {
    const upto = track.steps.slice(0, Math.min(n, track.steps.length - 1) + 1);
    const line = (kind: string, pts: [number, number][]) =>
      features.push({ type: "Feature", properties: { kind }, geometry: { type: "LineString", coordinates: pts } });
    line("dr", upto.filter((s) => Number.isFinite(s.dr_x_m)).map((s) => floorLonLat(fp, s.dr_x_m, s.dr_y_m)));
    line("matched", upto.map((s) => floorLonLat(fp, s.x_m, s.y_m)));
    const cur = upto[upto.length - 1];
    features.push({ type: "Feature", properties: { kind: "position" }, geometry: { type: "Point", coordinates: floorLonLat(fp, cur.x_m, cur.y_m) } });
  }
  return { type: "FeatureCollection", features };
}
