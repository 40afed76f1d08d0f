/**
 * The first-run tour of the editor, as a pure state machine (iD's walkthrough, in three
 * steps): make a drag, meet a refusal, submit. Each step advances on what the operator
 * actually did, read from two successive editor states.
 */
import { type EditorState, currentEdits, editCount } from "../state/editor";
import type { EditRules } from "../state/types";

export type TourStep = "drag" | "refusal" | "submit" | "done";

export const TOUR_STEPS: readonly Exclude<TourStep, "done">[] = ["drag", "refusal", "submit"];

/** A move was added or changed between `prev` and `next` (a drag that the rules allowed). */
function moved(prev: EditorState, next: EditorState): boolean {
  const a = currentEdits(prev).moves;
  const b = currentEdits(next).moves;
  if (a === b) return false;
  for (const [i, p] of b) if (a.get(i) !== p) return true;
  return false;
}

function submitted(prev: EditorState, next: EditorState): boolean {
  const wasBusy = prev.submit.kind === "sending" || prev.submit.kind === "waiting";
  if (!wasBusy) return false;
  // A run's submit ends "done"; a task's ends idle with the edits handed to the assignment.
  return next.submit.kind === "done" || (next.submit.kind === "idle" && !next.conflict && editCount(currentEdits(next)) === 0);
}

/** The step after `step`, given the change `prev` -> `next` of the editor state. */
export function tourAdvance(step: TourStep, prev: EditorState, next: EditorState): TourStep {
  switch (step) {
    case "drag": return moved(prev, next) ? "refusal" : step;
    case "refusal": return next.refusal && next.refusal !== prev.refusal ? "submit" : step;
    case "submit": return submitted(prev, next) ? "done" : step;
    default: return step;
  }
}

const TOUR_REACHABLE_MOVE_M = 100;

/** How to meet a refusal under this run's rules, in words. */
export function refusalHint(r: EditRules): string {
  if (r.lock_n > 0) return `Now drag one of the ${r.lock_n} keyframes just ${r.lock_direction === "both" ? "beside" : "after"} your move: they are locked (amber), so the move is refused.`;
  if (r.every_n > 1) return `Now drag a grey keyframe: only one keyframe in ${r.every_n} may move, so the move is refused.`;
  // Every run has a distance limit, but only a short one can be met by a drag on screen.
  if (r.max_move_m <= TOUR_REACHABLE_MOVE_M) return `Now drag a keyframe more than ${r.max_move_m} m from where it was recorded: that is too far, so the move is refused.`;
  return "Now drag a keyframe past its neighbour along the track: the track would run backwards, so the move is refused.";
}

/** What each step asks the operator to do. */
export function tourText(step: TourStep, rules: EditRules | null): { title: string; body: string } {
  switch (step) {
    case "drag":
      return { title: "Drag a keyframe", body: "Press on a blue keyframe and drag it to where the vehicle really was. The track around it follows when you let go; Ctrl+Z undoes it." };
    case "refusal":
      return { title: "Meet a refusal", body: rules ? refusalHint(rules) : "Now try a move the rules do not allow." };
    case "submit":
      return { title: "Submit", body: "The reason is shown where you dropped it, and nothing was changed. Now write a comment if you like and press the highlighted Submit button: your edits become a new revision." };
    default:
      return { title: "That is all", body: "Press ? at any time for every shortcut; Help in the top bar explains the rest." };
  }
}
