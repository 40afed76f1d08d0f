/**
 * Undo/redo over immutable Edits, as iD's history does over graphs: each step stores the
 * whole Edits value it produced and a label ("Move keyframe 40"), so one drag is one undo.
 */
import { EMPTY_EDITS, type Edits } from "./types";

export interface HistoryStep {
  label: string;
  edits: Edits;
}

export interface History {
  /** steps[0] is the base (no edits); `at` points at the current step. */
  readonly steps: readonly HistoryStep[];
  readonly at: number;
}

export function historyNew(base: Edits = EMPTY_EDITS): History {
  return { steps: [{ label: "Start", edits: base }], at: 0 };
}

export function historyCurrent(h: History): Edits {
  return h.steps[h.at].edits;
}

/** Append a step after the current one, dropping any redo tail. */
export function historyPerform(h: History, label: string, edits: Edits): History {
  return { steps: [...h.steps.slice(0, h.at + 1), { label, edits }], at: h.at + 1 };
}

/**
 * As `historyPerform`, but a step with the same label right after the last one replaces it:
 * the arrow-key nudges of one keyframe are one undo step, as a drag is.
 */
export function historyPerformMerged(h: History, label: string, edits: Edits): History {
  const last = h.at === h.steps.length - 1 && h.at > 0 && h.steps[h.at].label === label;
  return last ? { steps: [...h.steps.slice(0, h.at), { label, edits }], at: h.at } : historyPerform(h, label, edits);
}

export function canUndo(h: History): boolean {
  return h.at > 0;
}

export function canRedo(h: History): boolean {
  return h.at < h.steps.length - 1;
}

export function historyUndo(h: History): History {
  return canUndo(h) ? { ...h, at: h.at - 1 } : h;
}

export function historyRedo(h: History): History {
  return canRedo(h) ? { ...h, at: h.at + 1 } : h;
}

/** Label of the step undo would revert, or null. */
export function undoLabel(h: History): string | null {
  return canUndo(h) ? h.steps[h.at].label : null;
}

export function redoLabel(h: History): string | null {
  return canRedo(h) ? h.steps[h.at + 1].label : null;
}
