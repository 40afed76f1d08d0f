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
import type { Edits, LonLat, Refusal, RunDoc, Suggestion, SuggestionsReady, SuggestionsState } from "../state/types";

export type { Suggestion, SuggestionsReady, SuggestionsState };

/** Suggestions worth offering: adjustable keyframes the match would move by at least `minMoveM`. */
export function offered(items: readonly Suggestion[], minMoveM = 0.5): Suggestion[] {
  return items.filter((s) => s.adjustable && s.moved_m >= minMoveM);
}

/** Suggestions not yet staged at their suggested position. */
export function pending(items: readonly Suggestion[], edits: Edits, minMoveM = 0.5): Suggestion[] {
  return offered(items, minMoveM).filter((s) => !edits.suggested?.has(s.index));
}

/** Suggestions still to decide: offered, not accepted, not skipped, in keyframe order. */
export function todo(st: SuggestionsReady, edits: Edits): Suggestion[] {
  return pending(st.items, edits).filter((s) => !st.skipped.has(s.index)).sort((a, b) => a.index - b.index);
}

/** The list the operator steps through: every offered suggestion, in keyframe order. */
export function listed(st: SuggestionsReady): Suggestion[] {
  return offered(st.items).sort((a, b) => a.index - b.index);
}

export function focused(st: SuggestionsReady): Suggestion | null {
  return st.focus === null ? null : (listed(st).find((s) => s.index === st.focus) ?? null);
}

/** Fresh suggestions from the server: shown, none skipped, the first one to decide focused. */
export function suggestionsReady(r: ReturnType<typeof suggestionsFrom>, edits: Edits): SuggestionsReady {
  const st: SuggestionsReady = { kind: "ready", ...r, focus: null, skipped: new Set(), shown: true };
  return { ...st, focus: todo(st, edits)[0]?.index ?? null };
}

/** Focus the suggestion of keyframe `index` (a click on its point or its row): never accepts. */
export function focusSuggestion(st: SuggestionsReady, index: number): SuggestionsReady {
  return listed(st).some((s) => s.index === index) ? { ...st, focus: index } : st;
}

/** Focus the next (`d` = +1) or previous (-1) suggestion of the list, stopping at its ends. */
export function stepSuggestion(st: SuggestionsReady, d: 1 | -1): SuggestionsReady {
  const list = listed(st);
  if (list.length === 0) return st;
  const at = list.findIndex((s) => s.index === st.focus);
  const next = at < 0 ? (d > 0 ? 0 : list.length - 1) : Math.max(0, Math.min(list.length - 1, at + d));
  return { ...st, focus: list[next].index };
}

/** The first suggestion still to decide after `index` (wrapping round), or null when none is left. */
function nextTodo(st: SuggestionsReady, edits: Edits, index: number | null): number | null {
  const left = todo(st, edits);
  if (left.length === 0) return null;
  return (left.find((s) => index === null || s.index > index) ?? left[0]).index;
}

/** Pass over the focused suggestion: it stays on the map, is left out of "Accept all", and the next one is focused. */
export function skipSuggestion(st: SuggestionsReady, edits: Edits): SuggestionsReady {
  if (st.focus === null) return st;
  const skipped = new Set(st.skipped);
  skipped.add(st.focus);
  const next: SuggestionsReady = { ...st, skipped };
  return { ...next, focus: nextTodo(next, edits, st.focus) };
}

/** After the focused suggestion was accepted (`edits` include it): focus the next one to decide. */
export function focusAfterAccept(st: SuggestionsReady, edits: Edits): SuggestionsReady {
  return { ...st, focus: nextTodo(st, edits, st.focus) };
}

export function toggleSuggestionsShown(st: SuggestionsReady): SuggestionsReady {
  return { ...st, shown: !st.shown };
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
export function suggestionsFrom(body: unknown): { revision: number; items: Suggestion[]; offRoad: number; timeMs: number; matcher: string } {
  const b = body as { revision?: unknown; items?: unknown; off_road?: unknown; time_ms?: unknown; matcher?: unknown };
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
  return { revision: Number(b.revision), items, offRoad: Number(b.off_road ?? 0), timeMs: Number(b.time_ms ?? 0),
    matcher: b.matcher === "grid" ? "grid" : "roads" };
}

type Feature = GeoJSON.Feature<GeoJSON.Geometry, Record<string, unknown>>;

/**
 * The suggestion layer: a dashed link from each keyframe (as displayed) to its suggestion,
 * the suggested points (accepted ones marked), and rings on off-road keyframes.
 */
export function suggestionsFC(items: readonly Suggestion[], positions: readonly LonLat[], edits: Edits, minMoveM = 0.5, focus: number | null = null): GeoJSON.FeatureCollection {
  const features: Feature[] = [];
  const offer = new Set(offered(items, minMoveM).map((s) => s.index));
  for (const s of items) {
    const at = positions[s.index];
    if (!at) continue;
    if (s.off_road) features.push({ type: "Feature", geometry: { type: "Point", coordinates: [at[0], at[1]] }, properties: { kind: "offroad", i: s.index } });
    if (!offer.has(s.index)) continue;
    const accepted = edits.suggested?.has(s.index) ?? false;
    if (!accepted) features.push({ type: "Feature", geometry: { type: "LineString", coordinates: [[at[0], at[1]], [s.lonlat[0], s.lonlat[1]]] }, properties: { kind: "link", i: s.index } });
    features.push({ type: "Feature", geometry: { type: "Point", coordinates: [s.lonlat[0], s.lonlat[1]] }, properties: { kind: "point", i: s.index, accepted, focus: s.index === focus, moved: Math.round(s.moved_m * 10) / 10 } });
  }
  const line = items.map((s) => [s.lonlat[0], s.lonlat[1]]);
  if (line.length >= 2) features.unshift({ type: "Feature", geometry: { type: "LineString", coordinates: line }, properties: { kind: "path" } });
  return { type: "FeatureCollection", features };
}
