/**
 * The conflict panel: the "someone else saved first" dialog after a refused submit, and
 * the softer banner when a newer revision arrives while there are unsaved edits.
 */
import { type EditorState, currentEdits, editCount } from "../../state/editor";
import { clear, h } from "../dom";
import { button } from "./toolbar";

export interface ConflictActions {
  reapply(): void;
  discard(): void;
}

export class ConflictPanel {
  readonly newerBox = h("div", { class: "newer-box", role: "status", "data-testid": "newer", hidden: true });
  readonly dialog = h("div", { class: "conflict", role: "alertdialog", "aria-modal": "true", "aria-labelledby": "conflict-h", "data-testid": "conflict", hidden: true });

  constructor(private readonly a: ConflictActions) {}

  render(s: EditorState, prev: EditorState | null): void {
    if (!prev || prev.newer !== s.newer) this.showNewer(s);
    if (!prev || prev.conflict !== s.conflict) this.showConflict(s);
  }

  private showNewer(s: EditorState): void {
    this.newerBox.hidden = s.newer === null;
    this.newerBox.replaceChildren(
      ...(s.newer === null
        ? []
        : [
            `Revision ${s.newer} was saved by someone else while you edit revision ${s.doc?.revision}; submitting now would conflict. `,
            button("Reload and re-apply my edits", this.a.reapply, { "data-testid": "newer-reapply" }),
          ]),
    );
  }

  private showConflict(s: EditorState): void {
    const box = this.dialog;
    box.hidden = !s.conflict;
    clear(box);
    if (!s.conflict) return;
    const n = editCount(currentEdits(s));
    const edits = `edit${n === 1 ? "" : "s"}`;
    const reapply = button(`Reload and re-apply my ${n} ${edits}`, this.a.reapply, { class: "primary", "data-testid": "conflict-reapply" });
    box.append(h("div", { class: "card" },
      h("h2", { id: "conflict-h" }, "This run has changed since you opened it"),
      h("p", {}, `Someone saved revision ${s.conflict.currentRevision ?? "(newer)"} while you were editing revision ${s.conflict.baseRevision}. Your ${n} unsaved ${edits} ${n === 1 ? "is" : "are"} kept in this browser.`),
      h("p", {}, "Reload the run and re-apply your edits on top of the new revision (edits that no longer pass the rules are listed), or discard them."),
      h("div", { class: "row" }, reapply, button("Discard my edits and reload", this.a.discard, { "data-testid": "conflict-discard" })),
    ));
    reapply.focus();
  }
}
