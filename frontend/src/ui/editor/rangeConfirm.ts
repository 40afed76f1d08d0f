/**
 * Asks before a range deletion: how many keyframes, and which moves it would drop (unsaved
 * ones and those of earlier revisions), with Delete focused (Enter) and Cancel (Escape, through the editor's keys).
 */
import { type EditorState, currentEdits } from "../../state/editor";
import { h, plural } from "../dom";
import { button } from "./toolbar";

/** The moves a deletion of `lo..hi` would drop, in keyframe order. */
export function movesInRange(s: EditorState, lo: number, hi: number): number[] {
  if (!s.doc) return [];
  const moved = new Set<number>();
  for (const k of currentEdits(s).moves.keys()) if (k >= lo && k <= hi) moved.add(k);
  for (let k = lo; k <= hi && k < s.doc.keyframes.length; k++) if (s.doc.keyframes[k].edited) moved.add(k);
  return [...moved].sort((a, b) => a - b);
}

export function rangeQuestion(s: EditorState, lo: number, hi: number): string {
  const n = hi - lo + 1;
  const drops = movesInRange(s, lo, hi);
  const what = lo === hi ? `keyframe ${lo}` : `keyframes ${lo}–${hi} (${plural(n, "keyframe")})`;
  const moves = drops.length ? ` This drops the ${drops.length === 1 ? "move" : "moves"} of keyframe${drops.length === 1 ? "" : "s"} ${drops.join(", ")}.` : " No move is dropped.";
  return `Delete ${what}?${moves}`;
}

export class RangeConfirm {
  readonly el = h("div", { class: "range-confirm card confirm", role: "alertdialog", "aria-labelledby": "range-q", "data-testid": "range-confirm", hidden: true });

  close(): void {
    this.el.hidden = true;
    this.el.replaceChildren();
  }

  ask(s: EditorState, from: number, to: number, onYes: () => void): void {
    const lo = Math.min(from, to), hi = Math.max(from, to);
    const close = () => this.close();
    const yes = button(`Delete ${plural(hi - lo + 1, "keyframe")}`, () => {
      close();
      onYes();
    }, { class: "primary", "data-testid": "range-yes" });
    const no = button("Cancel", close, { "data-testid": "range-no" });
    this.el.replaceChildren(h("p", { id: "range-q", "data-testid": "range-question" }, rangeQuestion(s, lo, hi)), h("div", { class: "row" }, yes, no));
    this.el.hidden = false;
    yes.focus();
  }
}
