/**
 * Edit actions, as iD's: each is a labelled pure function from the current edits (and the
 * run they apply to) to new edits, or a refusal by the engine's rules. Tested without a DOM.
 */
import { checkNewMove } from "../rules/apply";
import type { Edits, LonLat, Refusal, RunDoc } from "../state/types";

export type EditResult = { ok: true; edits: Edits } | { ok: false; refusal: Refusal };

export interface EditAction {
  label: string;
  apply(doc: RunDoc, edits: Edits): EditResult;
}

function ok(edits: Edits): EditResult {
  return { ok: true, edits };
}

/** Move keyframe `index` to `lonlat`, if the rules allow it. */
export function actionMoveKeyframe(index: number, lonlat: LonLat): EditAction {
  return {
    label: `Move keyframe ${index}`,
    apply(doc, edits) {
      const refusal = checkNewMove(doc, edits, index, lonlat);
      if (refusal) return { ok: false, refusal };
      const moves = new Map(edits.moves);
      moves.set(index, [lonlat[0], lonlat[1]]);
      if (edits.suggested?.has(index)) {
        // Moved by hand now: an operator's move, no longer a machine suggestion.
        const suggested = new Set(edits.suggested);
        suggested.delete(index);
        return ok({ ...edits, moves, suggested, accept: false });
      }
      return ok({ ...edits, moves, accept: false });
    },
  };
}

/** A keyboard nudge of keyframe `index` to `lonlat`: a move, labelled so that consecutive nudges of one keyframe merge. */
export function actionNudgeKeyframe(index: number, lonlat: LonLat): EditAction {
  return { ...actionMoveKeyframe(index, lonlat), label: `Nudge keyframe ${index}` };
}

/** Mark keyframes `from..to` (inclusive, either order) for deletion; drops their moves. */
export function actionMarkDeleted(from: number, to: number = from): EditAction {
  const lo = Math.min(from, to);
  const hi = Math.max(from, to);
  return {
    label: lo === hi ? `Delete keyframe ${lo}` : `Delete keyframes ${lo}–${hi}`,
    apply(doc, edits) {
      if (lo < 0 || hi >= doc.keyframes.length) {
        return { ok: false, refusal: { index: lo < 0 ? lo : hi, reason: "out_of_range", message: `There is no keyframe ${lo < 0 ? lo : hi}; this run has ${doc.keyframes.length} keyframes.` } };
      }
      const deleted = new Set(edits.deleted);
      const moves = new Map(edits.moves);
      for (let k = lo; k <= hi; k++) {
        deleted.add(k);
        moves.delete(k);
      }
      return ok({ ...edits, moves, deleted, accept: false });
    },
  };
}

/** Take back deletion marks on `from..to`. */
export function actionRestore(from: number, to: number = from): EditAction {
  const lo = Math.min(from, to);
  const hi = Math.max(from, to);
  return {
    label: lo === hi ? `Restore keyframe ${lo}` : `Restore keyframes ${lo}–${hi}`,
    apply(_doc, edits) {
      const deleted = new Set(edits.deleted);
      for (let k = lo; k <= hi; k++) deleted.delete(k);
      return ok({ ...edits, deleted });
    },
  };
}

/** Undo the move of one keyframe (back to the loaded position). */
export function actionUnmove(index: number): EditAction {
  return {
    label: `Put back keyframe ${index}`,
    apply(_doc, edits) {
      if (!edits.moves.has(index)) return ok(edits);
      const moves = new Map(edits.moves);
      moves.delete(index);
      return ok({ ...edits, moves });
    },
  };
}

/** Accept the run as it is: no moves or deletions, an explicit verdict. */
export function actionAcceptAsIs(): EditAction {
  return {
    label: "Accept run as is",
    apply(_doc, _edits) {
      return ok({ moves: new Map(), deleted: new Set(), accept: true });
    },
  };
}

/** Drop every unsaved edit (itself one undoable step). */
export function actionReset(): EditAction {
  return {
    label: "Reset all edits",
    apply() {
      return ok({ moves: new Map(), deleted: new Set(), accept: false });
    },
  };
}
