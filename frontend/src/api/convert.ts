/**
 * Conversions between the server's JSON and the editor's model (pure; unit-tested).
 */
import { rulesFromJson } from "../rules/rules";
import type { Drift, Edits, Keyframe, LonLat, RunDoc } from "../state/types";

interface KeyframeProps {
  index: number;
  t?: number;
  heading_deg?: number;
  adjustable?: boolean;
  locked?: boolean;
  edited?: boolean;
  deleted?: boolean;
  flagged?: boolean;
  has_images?: boolean;
  images?: (string | number)[];
  reported?: [number, number] | null;
  correction_m?: number | null;
  sigma_m?: number | null;
}

/** Parse `GET /runs/{id}/keyframes` (a GeoJSON FeatureCollection with extras on top). */
export function docFromKeyframes(runId: string, name: string, fc: Record<string, unknown>): RunDoc {
  const features = (fc.features ?? []) as { geometry: { coordinates: number[] }; properties: KeyframeProps }[];
  const keyframes: Keyframe[] = features.map((f, n) => {
    const p = f.properties ?? ({} as KeyframeProps);
    const c = f.geometry.coordinates;
    const lonlat: LonLat = [c[0], c[1]];
    const index = typeof p.index === "number" ? p.index : n;
    if (index !== n) throw new Error(`keyframe feature ${n} has index ${index}: the server must send keyframes in order`);
    return {
      index,
      t_s: Number(p.t ?? 0),
      lonlat,
      reported: p.reported ? [p.reported[0], p.reported[1]] : lonlat,
      heading_deg: Number(p.heading_deg ?? 0),
      adjustable: Boolean(p.adjustable),
      locked: Boolean(p.locked),
      edited: Boolean(p.edited),
      deleted: Boolean(p.deleted),
      flagged: Boolean(p.flagged),
      images: (p.images ?? []).map(String),
      correction_m: Number(p.correction_m ?? 0),
      sigma_m: typeof p.sigma_m === "number" && Number.isFinite(p.sigma_m) ? p.sigma_m : null,
    };
  });
  return {
    runId,
    name,
    revision: Number(fc.revision ?? 0),
    rules: rulesFromJson(fc.rules as never),
    keyframes,
    drift: driftFrom(fc.drift),
    baseMoves: new Map(),
  };
}

/** Moves of a revision's cumulative edit set (`[[k, lon, lat, alt], ...]`). */
export function baseMovesFrom(editSet: Record<string, unknown> | null | undefined): Map<number, LonLat> {
  const out = new Map<number, LonLat>();
  for (const m of (editSet?.moves ?? []) as unknown[]) {
    if (Array.isArray(m) && m.length >= 3) out.set(Number(m[0]), [Number(m[1]), Number(m[2])]);
  }
  return out;
}

/** The drift estimate, shown as an offset and a spread (m) when the server gives them. */
export function driftFrom(raw: unknown): Drift | null {
  if (!raw || typeof raw !== "object") return null;
  const d = raw as Record<string, unknown>;
  const num = (v: unknown) => (typeof v === "number" && Number.isFinite(v) ? v : null);
  let offset = num(d.offset_m);
  const enu = d.offset_enu_m;
  if (offset === null && Array.isArray(enu) && num(enu[0]) !== null && num(enu[1]) !== null) offset = Math.hypot(Number(enu[0]), Number(enu[1]));
  const cal = d.calibration && typeof d.calibration === "object" ? d.calibration as Record<string, unknown> : null;
  return {
    offset_m: offset,
    spread_m: num(d.spread_m),
    max_bias_m: num(d.max_bias_m),
    detected: typeof d.detected === "boolean" ? d.detected : null,
    n_edits: num(d.n_edits),
    model: cal && typeof cal.model === "string" ? cal.model : null,
    cv_rmse_m: cal ? num(cal.cv_rmse_m) : null,
    predicted_rmse_m: cal ? num(cal.predicted_rmse_m) : null,
  };
}

/** The body of a preview or submit: moves as `{index, lon, lat}`, deletions as indices. */
export function editsBody(e: Edits): { moves: { index: number; lon: number; lat: number; kind: "move" | "suggestion" }[]; deleted: number[]; accept: boolean } {
  return {
    moves: [...e.moves].sort((a, b) => a[0] - b[0]).map(([index, p]) => ({ index, lon: p[0], lat: p[1], kind: e.suggested?.has(index) ? "suggestion" as const : "move" as const })),
    deleted: [...e.deleted].sort((a, b) => a - b),
    accept: e.accept,
  };
}

/** Edits back from a body (to restore unsaved work kept in the browser). */
export function editsFromBody(b: { moves?: { index: number; lon: number; lat: number; kind?: string }[]; deleted?: number[]; accept?: boolean }): Edits {
  const suggested = (b.moves ?? []).filter((m) => m.kind === "suggestion").map((m) => m.index);
  return {
    moves: new Map((b.moves ?? []).map((m) => [m.index, [m.lon, m.lat] as LonLat])),
    deleted: new Set(b.deleted ?? []),
    accept: Boolean(b.accept),
    ...(suggested.length ? { suggested: new Set(suggested) } : {}),
  };
}
