/**
 * State -> state transitions of the editor: performing a labelled edit (or recording its
 * refusal), undo/redo, staging while dragging, preview results, selection, conflicts.
 */
import {
  type EditorState,
  type ModeName,
  currentEdits,
  displayPositions,
  editorNew,
} from "../state/editor";
import {
  historyNew,
  historyPerform,
  historyPerformMerged,
  historyRedo,
  historyUndo,
} from "../state/history";
import { offsetLonLat } from "../rules/geodesy";
import type { Drift, Edits, LonLat, Refusal, RunDoc } from "../state/types";
import { type EditAction, actionNudgeKeyframe } from "./edits";

/** Apply `action`: a new history step, or the refusal placed at `at` (edits unchanged). */
export function perform(s: EditorState, action: EditAction, at?: LonLat, merge = false): EditorState {
  if (!s.doc) return s;
  const r = action.apply(s.doc, currentEdits(s));
  if (!r.ok) {
    const where = at ?? s.doc.keyframes[r.refusal.index]?.lonlat ?? [0, 0];
    return { ...s, staging: null, refusal: { ...r.refusal, at: where } };
  }
  const history = (merge ? historyPerformMerged : historyPerform)(s.history, action.label, r.edits);
  return { ...s, staging: null, refusal: null, history };
}

/**
 * Nudge the selected keyframe by `eastM`/`northM` metres from where it is drawn: a move by
 * the same rules as a drag (a refusal is shown at the nudged position), and consecutive
 * nudges of one keyframe are one undo step.
 */
export function nudgeSelected(s: EditorState, eastM: number, northM: number): EditorState {
  const i = s.selected;
  if (i === null || !s.doc) return s;
  const to = offsetLonLat(currentEdits(s).moves.get(i) ?? displayPositions(s)[i], eastM, northM);
  return perform(s, actionNudgeKeyframe(i, to), to, true);
}

export function undo(s: EditorState): EditorState {
  return { ...s, history: historyUndo(s.history), refusal: null, staging: null };
}

export function redo(s: EditorState): EditorState {
  return { ...s, history: historyRedo(s.history), refusal: null, staging: null };
}

/** Load a run's revision; keeps `carry` edits as one step (re-applied after a conflict). */
export function loadDoc(s: EditorState, doc: RunDoc, carry?: { label: string; edits: Edits }): EditorState {
  let history = historyNew();
  if (carry) history = historyPerform(history, carry.label, carry.edits);
  return {
    ...editorNew(),
    showGhost: s.showGhost,
    doc,
    history,
    lastSolverTimeS: s.lastSolverTimeS,
  };
}

export function stageDrag(s: EditorState, index: number, lonlat: LonLat): EditorState {
  return { ...s, staging: { index, lonlat }, refusal: null, selected: index };
}

export function clearStaging(s: EditorState): EditorState {
  return s.staging ? { ...s, staging: null } : s;
}

export function setMode(s: EditorState, mode: ModeName): EditorState {
  // A range starts at the first keyframe clicked in the mode, never at an earlier selection.
  return s.mode === mode ? s : { ...s, mode, rangeAnchor: null };
}

export function select(s: EditorState, index: number | null): EditorState {
  if (index !== null && (!s.doc || index < 0 || index >= s.doc.keyframes.length)) return s;
  return { ...s, selected: index };
}

/** Next/previous keyframe (wrapping at the ends is refused: stays put). */
export function selectStep(s: EditorState, step: number): EditorState {
  if (!s.doc || s.doc.keyframes.length === 0) return s;
  const from = s.selected ?? (step > 0 ? -1 : s.doc.keyframes.length);
  const to = Math.min(s.doc.keyframes.length - 1, Math.max(0, from + step));
  return select(s, to);
}

/** Next adjustable keyframe after the selection (wraps around to the start). */
export function selectNextAdjustable(s: EditorState): EditorState {
  if (!s.doc) return s;
  const n = s.doc.keyframes.length;
  const start = s.selected ?? -1;
  for (let d = 1; d <= n; d++) {
    const k = (start + d + n) % n;
    const kf = s.doc.keyframes[k];
    if (kf.adjustable && !kf.locked && !kf.deleted) return select(s, k);
  }
  return s;
}

export function setPreview(
  s: EditorState,
  forEdits: Edits,
  positions: LonLat[],
  solverTimeS: number | null,
  drift: Drift | null = null,
  flags: Refusal[] = [],
): EditorState {
  return {
    ...s,
    preview: { positions, forEdits, solverTimeS, drift, flags },
    previewPending: false,
    lastSolverTimeS: solverTimeS ?? s.lastSolverTimeS,
    error: null,
  };
}

export function setError(s: EditorState, error: string | null): EditorState {
  return { ...s, error, previewPending: false };
}

export function toggleGhost(s: EditorState): EditorState {
  return { ...s, showGhost: !s.showGhost };
}

export function dismissRefusal(s: EditorState): EditorState {
  return s.refusal ? { ...s, refusal: null } : s;
}
