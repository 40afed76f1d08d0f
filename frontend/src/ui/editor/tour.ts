/**
 * The tour card in the editor's side panel: shown on a browser's first visit to a run (and
 * when restarted from Help); it never covers the map. The steps are `actions/tour.ts`.
 */
import { TOUR_STEPS, type TourStep, tourAdvance, tourText } from "../../actions/tour";
import type { EditorState } from "../../state/editor";
import type { EditRules } from "../../state/types";
import { h } from "../dom";

const DONE_KEY = "posefix.tour.done";

/** Show the tour again on the next run opened (or now, in an open editor). */
export function restartTour(): void {
  try {
    localStorage.removeItem(DONE_KEY);
  } catch {
    /* storage disabled: the tour shows anyway */
  }
  window.dispatchEvent(new Event("posefix:tour"));
}

function tourDone(): boolean {
  try {
    return localStorage.getItem(DONE_KEY) === "1";
  } catch {
    return false;
  }
}

export class TourCard {
  readonly el = h("section", { class: "tour card", "aria-label": "Tour", "data-testid": "tour", "aria-live": "polite" });
  step: TourStep | null;

  /** `onStep` lets the view mark what the step points at (the editor root's data-tour-step). */
  constructor(private readonly onStep: (step: TourStep | null) => void) {
    this.step = tourDone() ? null : "drag";
    window.addEventListener("posefix:tour", this.restart);
  }

  private restart = () => {
    this.step = "drag";
    this.show(null);
  };

  dispose(): void {
    window.removeEventListener("posefix:tour", this.restart);
  }

  private finish(): void {
    try {
      localStorage.setItem(DONE_KEY, "1");
    } catch {
      /* storage disabled */
    }
    this.step = null;
    this.show(null);
  }

  update(s: EditorState, prev: EditorState): void {
    if (this.step === null || this.step === "done") return;
    const next = tourAdvance(this.step, prev, s);
    if (next === this.step) return;
    this.step = next;
    if (next === "done") {
      try {
        localStorage.setItem(DONE_KEY, "1");
      } catch {
        /* storage disabled */
      }
    }
    this.show(s);
  }

  show(s: EditorState | null): void {
    this.onStep(this.step);
    if (this.step === null) {
      this.el.hidden = true;
      this.el.replaceChildren();
      return;
    }
    this.el.hidden = false;
    const t = tourText(this.step, s?.doc?.rules ?? this.rules);
    if (s?.doc) this.rules = s.doc.rules;
    const n = TOUR_STEPS.indexOf(this.step as (typeof TOUR_STEPS)[number]);
    this.el.dataset.step = this.step;
    this.el.replaceChildren(
      h("p", { class: "tour-count muted" }, n >= 0 ? `Tour · step ${n + 1} of ${TOUR_STEPS.length}` : "Tour · finished"),
      h("h2", { "data-testid": "tour-title" }, t.title),
      h("p", { "data-testid": "tour-text" }, t.body),
      h("button", { type: "button", "data-testid": "tour-close", onclick: () => this.finish() }, this.step === "done" ? "Close" : "Skip the tour"),
    );
  }

  private rules: EditRules | null = null;
}
