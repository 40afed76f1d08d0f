/**
 * Pure geometry of the floor view: floor metres (x east, y north, origin at the floor's
 * south-west corner) <-> canvas pixels (y down), and the replay's derived values. No DOM.
 */
import type { WalkStep, WalkTrack, WaypointError } from "./api";

export interface View {
  scale: number; // px per metre
  ox: number;
  oy: number;
  heightPx: number;
}

/** Fit a `width_m` x `height_m` floor into `w` x `h` px with `pad` px margins. */
export function fitView(width_m: number, height_m: number, w: number, h: number, pad = 10): View {
  const scale = Math.min((w - 2 * pad) / width_m, (h - 2 * pad) / height_m);
  return { scale, ox: (w - width_m * scale) / 2, oy: (h - height_m * scale) / 2, heightPx: h };
}

export function toPx(v: View, x: number, y: number): [number, number] {
  return [v.ox + x * v.scale, v.heightPx - (v.oy + y * v.scale)];
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
