/**
 * The editor's whole state and the views derived from it. Knows nothing of MapLibre:
 * the map adapter and the UI read it, actions produce new values of it.
 */
import { distanceM } from "../rules/geodesy";
import { lockedMask } from "../rules/rules";
import { type History, historyCurrent, historyNew } from "./history";
import type { Drift, Edits, LonLat, Refusal, RunDoc, SuggestionsState } from "./types";

export type ModeName = "browse" | "drag" | "select-range";

export type KeyframeStatus = "deleted" | "moved" | "locked" | "flagged" | "adjustable" | "fixed";

export interface Preview {
  /** Re-optimised position of every keyframe for `forEdits`. */
  positions: LonLat[];
  forEdits: Edits;
  solverTimeS: number | null;
  /** The drift estimate with these edits. */
  drift: Drift | null;
  /** Moves accepted with a flag (e.g. order under the "flag" rule). */
  flags: Refusal[];
}

export type SubmitState =
  | { kind: "idle" }
  | { kind: "sending" }
  | { kind: "waiting"; jobId: string; progress: number }
  | { kind: "error"; message: string }
  | { kind: "done"; revision: number };

export interface EditorState {
  doc: RunDoc | null;
  history: History;
  preview: Preview | null;
  previewPending: boolean;
  /** The keyframe being dragged and where the pointer has it now (not yet an edit). */
  staging: { index: number; lonlat: LonLat } | null;
  /** The last refusal, placed where the operator acted. */
  refusal: (Refusal & { at: LonLat }) | null;
  selected: number | null;
  /** Anchor of a range being selected (select-range mode). */
  rangeAnchor: number | null;
  showGhost: boolean;
  mode: ModeName;
  conflict: { baseRevision: number; currentRevision: number | null } | null;
  /** A newer revision someone else saved while this one is open (server-sent event). */
  newer: number | null;
  submit: SubmitState;
  /** A network or server error to show plainly. */
  error: string | null;
  lastSolverTimeS: number | null;
  /** Map-matching suggestions, for the revision they were computed on. */
  suggestions: SuggestionsState;
  /** Two revisions compared on the map (history panel), or null. */
  compare: RevisionCompare | null;
}

export interface RevisionCompare {
  from: number;
  to: number;
  /** Keyframe positions at each revision. */
  fromPositions: LonLat[];
  toPositions: LonLat[];
  /** Horizontal distance (m) per keyframe between the two. */
  displacement: number[];
  /** Keyframes that moved more than 1 mm. */
  moved: number[];
}

export function editorNew(): EditorState {
  return {
    doc: null,
    history: historyNew(),
    preview: null,
    previewPending: false,
    staging: null,
    refusal: null,
    selected: null,
    rangeAnchor: null,
    showGhost: true,
    mode: "browse",
    conflict: null,
    newer: null,
    submit: { kind: "idle" },
    error: null,
    lastSolverTimeS: null,
    suggestions: { kind: "idle" },
    compare: null,
  };
}

export function currentEdits(s: EditorState): Edits {
  return historyCurrent(s.history);
}

export function editCount(e: Edits): number {
  return e.moves.size + e.deleted.size + (e.accept ? 1 : 0);
}

/** Keyframes locked by the unsaved moves and earlier edits (the engine's lock span). */
export function lockedNow(s: EditorState): Set<number> {
  if (!s.doc) return new Set();
  const e = currentEdits(s);
  const edited = new Set<number>(e.moves.keys());
  for (const k of s.doc.keyframes) if (k.edited) edited.add(k.index);
  const mask = lockedMask(s.doc.keyframes.length, edited, s.doc.rules);
  const out = new Set<number>();
  mask.forEach((m, i) => m && out.add(i));
  return out;
}

/** One status per keyframe, the most important first: what the legend explains. */
export function keyframeStatuses(s: EditorState): KeyframeStatus[] {
  if (!s.doc) return [];
  const e = currentEdits(s);
  const locked = lockedNow(s);
  return s.doc.keyframes.map((k) => {
    if (k.deleted || e.deleted.has(k.index)) return "deleted";
    if (e.moves.has(k.index) || k.edited) return "moved";
    if (k.locked || locked.has(k.index)) return "locked";
    if (k.flagged) return "flagged";
    return k.adjustable ? "adjustable" : "fixed";
  });
}

/** Whether the preview on screen was computed for the current edits. */
export function previewIsCurrent(s: EditorState): boolean {
  return s.preview !== null && s.preview.forEdits === currentEdits(s);
}

/**
 * Where each keyframe is drawn: the server's re-optimised preview when it matches the edits,
 * else the loaded positions with the moves put in (the neighbours catch up when it arrives).
 */
export function displayPositions(s: EditorState): LonLat[] {
  if (!s.doc) return [];
  if (s.preview && s.preview.positions.length === s.doc.keyframes.length && previewIsCurrent(s)) {
    return s.preview.positions;
  }
  const moves = currentEdits(s).moves;
  return s.doc.keyframes.map((k) => moves.get(k.index) ?? k.lonlat);
}

/** Correction magnitude (m) per keyframe: displayed position against the reported one. */
export function correctionMagnitudes(s: EditorState): number[] {
  if (!s.doc) return [];
  const pos = displayPositions(s);
  return s.doc.keyframes.map((k, i) => distanceM(k.reported, pos[i]));
}

/** The drift estimate to show: the preview's when current, else the loaded revision's. */
export function currentDrift(s: EditorState): Drift | null {
  return previewIsCurrent(s) && s.preview!.drift ? s.preview!.drift : (s.doc?.drift ?? null);
}

/** The suggestions that apply to the shown revision (those of an older one are dropped). */
export function currentSuggestions(s: EditorState): SuggestionsState {
  const g = s.suggestions;
  return g.kind === "ready" && s.doc && s.doc.revision !== g.revision ? { kind: "idle" } : g;
}
