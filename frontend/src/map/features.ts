/**
 * Pure builders from editor state to GeoJSON (no MapLibre here, so they are unit-tested).
 */
import {
  type EditorState,
  type KeyframeStatus,
  displayPositions,
  keyframeStatuses,
} from "../state/editor";
import type { LonLat } from "../state/types";

export type FC = GeoJSON.FeatureCollection;

export const STATUS_COLORS: Record<KeyframeStatus, string> = {
  adjustable: "#2563eb",
  locked: "#d97706",
  moved: "#16a34a",
  deleted: "#dc2626",
  flagged: "#a21caf",
  fixed: "#64748b",
};

/** Machine suggestions and off-road flags: their own pink, apart from every keyframe status. */
export const SUGGESTION_COLOR = "#db2777";
export const OFFROAD_COLOR = "#9d174d";

export const STATUS_LABELS: Record<KeyframeStatus, string> = {
  adjustable: "Adjustable",
  locked: "Locked",
  moved: "Moved",
  deleted: "Marked for deletion",
  flagged: "Flagged",
  fixed: "Not adjustable",
};

export function emptyFC(): FC {
  return { type: "FeatureCollection", features: [] };
}

function lineFC(coords: readonly LonLat[]): FC {
  if (coords.length < 2) return emptyFC();
  return {
    type: "FeatureCollection",
    features: [{ type: "Feature", properties: {}, geometry: { type: "LineString", coordinates: coords.map((c) => [c[0], c[1]]) } }],
  };
}

/** Keyframe points with `i` (index), `h` (heading, degrees clockwise from north), `s` (status). */
export function keyframesFC(s: EditorState): FC {
  if (!s.doc) return emptyFC();
  const pos = displayPositions(s);
  const st = keyframeStatuses(s);
  const features: GeoJSON.Feature[] = new Array(pos.length);
  for (let i = 0; i < pos.length; i++) {
    const k = s.doc.keyframes[i];
    features[i] = {
      type: "Feature",
      id: i,
      properties: { i, h: k.heading_deg, s: st[i] },
      geometry: { type: "Point", coordinates: [pos[i][0], pos[i][1]] },
    };
  }
  return { type: "FeatureCollection", features };
}

/** The track as drawn now (preview or loaded + moves), excluding deleted keyframes. */
export function trackFC(s: EditorState): FC {
  if (!s.doc) return emptyFC();
  const pos = displayPositions(s);
  const st = keyframeStatuses(s);
  return lineFC(pos.filter((_, i) => st[i] !== "deleted"));
}

/** The loaded revision's track: the faint ghost under a corrected preview. */
export function ghostFC(s: EditorState): FC {
  if (!s.doc || !s.showGhost) return emptyFC();
  return lineFC(s.doc.keyframes.map((k) => k.lonlat));
}

/** The keyframe being dragged and a line back to where it was. */
export function stagingFC(s: EditorState): FC {
  if (!s.doc || !s.staging) return emptyFC();
  const k = s.doc.keyframes[s.staging.index];
  const from = displayPositions(s)[s.staging.index] ?? k.lonlat;
  return {
    type: "FeatureCollection",
    features: [
      { type: "Feature", properties: { kind: "rubber" }, geometry: { type: "LineString", coordinates: [[from[0], from[1]], [s.staging.lonlat[0], s.staging.lonlat[1]]] } },
      { type: "Feature", properties: { kind: "point", h: k.heading_deg }, geometry: { type: "Point", coordinates: [s.staging.lonlat[0], s.staging.lonlat[1]] } },
    ],
  };
}

/** The selected keyframe and the range anchor, drawn as rings. */
export function selectionFC(s: EditorState): FC {
  if (!s.doc) return emptyFC();
  const pos = displayPositions(s);
  const features: GeoJSON.Feature[] = [];
  for (const [idx, kind] of [[s.selected, "selected"], [s.rangeAnchor, "anchor"]] as const) {
    if (idx !== null && pos[idx]) {
      features.push({ type: "Feature", properties: { kind }, geometry: { type: "Point", coordinates: [pos[idx][0], pos[idx][1]] } });
    }
  }
  return { type: "FeatureCollection", features };
}

/** Where a refusal happened (the operator's drop point). */
export function refusalFC(s: EditorState): FC {
  if (!s.refusal) return emptyFC();
  return {
    type: "FeatureCollection",
    features: [{ type: "Feature", properties: { reason: s.refusal.reason }, geometry: { type: "Point", coordinates: [s.refusal.at[0], s.refusal.at[1]] } }],
  };
}

/** [minLon, minLat, maxLon, maxLat] of the loaded keyframes, or null. */
export function bounds(s: EditorState): [number, number, number, number] | null {
  if (!s.doc || s.doc.keyframes.length === 0) return null;
  let a = Infinity, b = Infinity, c = -Infinity, d = -Infinity;
  for (const k of s.doc.keyframes) {
    a = Math.min(a, k.lonlat[0]); b = Math.min(b, k.lonlat[1]);
    c = Math.max(c, k.lonlat[0]); d = Math.max(d, k.lonlat[1]);
  }
  return [a, b, c, d];
}

/** Two revisions compared: each track, and a link per moved keyframe from one to the other. */
export function compareFC(s: EditorState): FC {
  const c = s.compare;
  if (!c) return emptyFC();
  const features: GeoJSON.Feature[] = [];
  const line = (pts: readonly LonLat[], which: string) =>
    pts.length >= 2 && features.push({ type: "Feature", properties: { kind: "track", which }, geometry: { type: "LineString", coordinates: pts.map((p) => [p[0], p[1]]) } });
  line(c.fromPositions, "from");
  line(c.toPositions, "to");
  for (const i of c.moved) {
    const a = c.fromPositions[i], b = c.toPositions[i];
    if (!a || !b) continue;
    features.push({ type: "Feature", properties: { kind: "link", i }, geometry: { type: "LineString", coordinates: [[a[0], a[1]], [b[0], b[1]]] } });
    features.push({ type: "Feature", properties: { kind: "moved", i }, geometry: { type: "Point", coordinates: [b[0], b[1]] } });
  }
  return { type: "FeatureCollection", features };
}
