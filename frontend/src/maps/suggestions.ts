/**
 * Map-matching suggestions in the run editor: pure state and actions (no DOM, no MapLibre).
 *
 * The server matches the run's keyframes to the OpenStreetMap drivable area and proposes a
 * position per keyframe. Accepting one stages an ordinary move (so the editing rules, the
 * live preview, undo and submit all apply) that is marked in `Edits.suggested`, and is sent
 * as `kind: "suggestion"`: a distinct, weaker kind of edit than an operator's own move.
 */
import type { EditAction, EditResult } from "../actions/edits";
import { checkNewMove } from "../rules/apply";
import type { Edits, LonLat, Refusal, RunDoc, Suggestion, SuggestionsState } from "../state/types";

export type { Suggestion, SuggestionsState };

/** Suggestions worth offering: adjustable keyframes the match would move by at least `minMoveM`. */
export function offered(items: readonly Suggestion[], minMoveM = 0.5): Suggestion[] {
  return items.filter((s) => s.adjustable && s.moved_m >= minMoveM);
}

/** Suggestions not yet staged at their suggested position. */
export function pending(items: readonly Suggestion[], edits: Edits, minMoveM = 0.5): Suggestion[] {
  return offered(items, minMoveM).filter((s) => !edits.suggested?.has(s.index));
}

function stage(doc: RunDoc, edits: Edits, s: Suggestion): EditResult {
  if (s.index < 0 || s.index >= doc.keyframes.length) {
    return { ok: false, refusal: { index: s.index, reason: "out_of_range", message: `There is no keyframe ${s.index}.` } };
  }
  const refusal = checkNewMove(doc, edits, s.index, s.lonlat);
  if (refusal) return { ok: false, refusal };
  const moves = new Map(edits.moves);
  moves.set(s.index, [s.lonlat[0], s.lonlat[1]]);
  const suggested = new Set(edits.suggested ?? []);
  suggested.add(s.index);
  return { ok: true, edits: { ...edits, moves, suggested, accept: false } };
}

/** Accept one suggestion: a move of its keyframe to the matched position, if the rules allow it. */
export function actionAcceptSuggestion(s: Suggestion): EditAction {
  return { label: `Accept suggestion for keyframe ${s.index}`, apply: (doc, edits) => stage(doc, edits, s) };
}

/**
 * Accept every suggestion in one step, in keyframe order. A suggestion the rules refuse
 * (e.g. locked by an earlier accepted one, or too far) is skipped; the step is refused only
 * when none can be accepted. `skipped` on the result lists what was left out.
 */
export function actionAcceptAllSuggestions(items: readonly Suggestion[]): EditAction & { skipped: Refusal[] } {
  const skipped: Refusal[] = [];
  const sorted = [...items].sort((a, b) => a.index - b.index);
  return {
    label: `Accept ${sorted.length} suggestion${sorted.length === 1 ? "" : "s"}`,
    skipped,
    apply(doc, edits) {
      skipped.length = 0;
      let cur = edits;
      let n = 0;
      for (const s of sorted) {
        const r = stage(doc, cur, s);
        if (r.ok) {
          cur = r.edits;
          n++;
        } else skipped.push(r.refusal);
      }
      if (n === 0) {
        const first = skipped[0] ?? { index: 0, reason: "none", message: "There is no suggestion to accept." };
        return { ok: false, refusal: { ...first, message: `No suggestion could be accepted: ${first.message}` } };
      }
      return { ok: true, edits: cur };
    },
  };
}

/** Server answer -> suggestions (validates the shape so a bad answer is an error, not a blank layer). */
export function suggestionsFrom(body: unknown): { revision: number; items: Suggestion[]; offRoad: number; timeMs: number } {
  const b = body as { revision?: unknown; items?: unknown; off_road?: unknown; time_ms?: unknown };
  if (!b || !Array.isArray(b.items)) throw new Error("The suggestions answer has no items.");
  const items = b.items.map((raw, i) => {
    const it = raw as Record<string, unknown>;
    const lon = Number(it.lon);
    const lat = Number(it.lat);
    if (!Number.isFinite(lon) || !Number.isFinite(lat)) throw new Error(`Suggestion ${i} has no position.`);
    return {
      index: Number(it.index),
      lonlat: [lon, lat] as LonLat,
      moved_m: Number(it.moved_m),
      off_road: Boolean(it.off_road),
      sigma_m: Number(it.sigma_m),
      adjustable: Boolean(it.adjustable),
    };
  });
  return { revision: Number(b.revision), items, offRoad: Number(b.off_road ?? 0), timeMs: Number(b.time_ms ?? 0) };
}

type Feature = GeoJSON.Feature<GeoJSON.Geometry, Record<string, unknown>>;

/**
 * The suggestion layer: a dashed link from each keyframe (as displayed) to its suggestion,
 * the suggested points (accepted ones marked), and rings on off-road keyframes.
 */
export function suggestionsFC(items: readonly Suggestion[], positions: readonly LonLat[], edits: Edits, minMoveM = 0.5): GeoJSON.FeatureCollection {
  const features: Feature[] = [];
  const offer = new Set(offered(items, minMoveM).map((s) => s.index));
  for (const s of items) {
    const at = positions[s.index];
    if (!at) continue;
    if (s.off_road) features.push({ type: "Feature", geometry: { type: "Point", coordinates: [at[0], at[1]] }, properties: { kind: "offroad", i: s.index } });
    if (!offer.has(s.index)) continue;
    const accepted = edits.suggested?.has(s.index) ?? false;
    if (!accepted) features.push({ type: "Feature", geometry: { type: "LineString", coordinates: [[at[0], at[1]], [s.lonlat[0], s.lonlat[1]]] }, properties: { kind: "link", i: s.index } });
    features.push({ type: "Feature", geometry: { type: "Point", coordinates: [s.lonlat[0], s.lonlat[1]] }, properties: { kind: "point", i: s.index, accepted, moved: Math.round(s.moved_m * 10) / 10 } });
  }
  const line = items.map((s) => [s.lonlat[0], s.lonlat[1]]);
  if (line.length >= 2) features.unshift({ type: "Feature", geometry: { type: "LineString", coordinates: line }, properties: { kind: "path" } });
  return { type: "FeatureCollection", features };
}
