/** The editor's toolbar: the buttons, and how they reflect the editor state. */
import type { EditorState } from "../../state/editor";
import { h } from "../dom";
import { toolbarState } from "./panels";

export interface ToolbarActions {
  undo(): void;
  redo(): void;
  toggleDelete(): void;
  toggleRange(): void;
  acceptAsIs(): void;
  reset(): void;
  toggleGhost(): void;
  images(): void;
  fit(): void;
  history(): void;
  submit(comment: string): void;
}

/** How the Submit control reads: a task page submits to its assignment. */
export interface SubmitOptions {
  label: string;
  commentLabel: string;
  testId: string;
}

export const RUN_SUBMIT: SubmitOptions = { label: "Submit", commentLabel: "Comment for this submission", testId: "submit" };

export function button(label: string, onclick: () => void, attrs: Record<string, unknown> = {}): HTMLButtonElement {
  return h("button", { type: "button", onclick, ...attrs }, label);
}

export class EditorToolbar {
  readonly el: HTMLElement;
  readonly title = h("h1", { class: "run-title" }, "Loading run…");
  readonly comment: HTMLInputElement;
  private readonly undoBtn: HTMLButtonElement;
  private readonly redoBtn: HTMLButtonElement;
  private readonly deleteBtn: HTMLButtonElement;
  private readonly rangeBtn: HTMLButtonElement;
  private readonly ghostBtn: HTMLButtonElement;
  private readonly imagesBtn: HTMLButtonElement;
  private readonly submitBtn: HTMLButtonElement;

  /** `extra`: more tools (the suggestions) placed after the view buttons. */
  constructor(a: ToolbarActions, extra: HTMLElement[], submit: SubmitOptions = RUN_SUBMIT) {
    this.undoBtn = button("↶ Undo", a.undo, { "data-testid": "undo" });
    this.redoBtn = button("↷ Redo", a.redo, { "data-testid": "redo" });
    this.deleteBtn = button("Delete", a.toggleDelete, { "data-testid": "delete", title: "Mark the selected keyframe for deletion (Delete)" });
    this.rangeBtn = button("Delete range…", a.toggleRange, { "data-testid": "delete-range", title: "Click the first and last keyframe of the range (R)" });
    const acceptBtn = button("Accept as is", a.acceptAsIs, { "data-testid": "accept", title: "The run needs no correction" });
    const resetBtn = button("Reset", a.reset, { "data-testid": "reset", title: "Drop all unsaved edits (undoable)" });
    this.ghostBtn = button("Ghost", a.toggleGhost, { "data-testid": "ghost", "aria-pressed": "true", title: "Show the loaded revision under the corrected track (G)" });
    this.imagesBtn = button("Images", a.images, { "data-testid": "images-button", title: "Images of the selected keyframe (I)" });
    const fitBtn = button("Fit", a.fit, { title: "Zoom to the whole run (F)" });
    const historyBtn = button("History", a.history, { "data-testid": "history", title: "Revisions, compare, revert (H)" });
    this.comment = h("input", { id: "submit-comment", placeholder: `${submit.commentLabel} (optional)`, "aria-label": submit.commentLabel });
    this.submitBtn = button(submit.label, () => a.submit(this.comment.value), { class: "primary", "data-testid": submit.testId });
    const sep = () => h("span", { class: "sep" });
    this.el = h("div", { class: "toolbar", role: "toolbar", "aria-label": "Editing tools" },
      this.title, this.undoBtn, this.redoBtn, sep(), this.deleteBtn, this.rangeBtn, acceptBtn, resetBtn, sep(), this.ghostBtn, this.imagesBtn, fitBtn, historyBtn,
      sep(), ...extra,
      h("span", { class: "grow" }), this.comment, this.submitBtn);
  }

  render(s: EditorState): void {
    if (s.doc) this.title.textContent = `${s.doc.name} · rev ${s.doc.revision}`;
    const tb = toolbarState(s);
    for (const [b, st] of [[this.undoBtn, tb.undo], [this.redoBtn, tb.redo]] as const) {
      b.disabled = !st.enabled;
      b.title = st.title;
      b.setAttribute("aria-label", st.title);
    }
    this.submitBtn.disabled = !tb.submitEnabled;
    this.deleteBtn.disabled = !tb.hasSelection;
    this.imagesBtn.disabled = !tb.hasSelection;
    this.ghostBtn.setAttribute("aria-pressed", String(s.showGhost));
    this.rangeBtn.setAttribute("aria-pressed", String(s.mode === "select-range"));
    this.rangeBtn.textContent = s.mode === "select-range" ? (s.rangeAnchor === null ? "Click first keyframe…" : "Click last keyframe…") : "Delete range…";
  }
}
