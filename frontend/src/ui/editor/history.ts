/**
 * The run's history panel: every revision with who, when, comment, task and review; two
 * picked revisions compared on the map (both tracks, the moved keyframes) and as a distance
 * chart; revert, for those allowed, after a confirmation that says what will change.
 */
import { type RevisionPublic, api } from "../../api/endpoints";
import { describeError } from "../../api/errors";
import type { EditorState, RevisionCompare } from "../../state/editor";
import type { Store } from "../../state/store";
import { fmtTime, h, plural } from "../dom";
import { CorrectionChart } from "./chart";
import type { EditorController } from "./controller";
import { button } from "./toolbar";

/** Roles the server lets revert (admin, reviewer, operator). */
const MAY_REVERT = new Set(["admin", "reviewer", "operator"]);


function reviewText(r: RevisionPublic): string {
  if (!r.review) return "";
  return `${r.review}${r.reviewer ? ` by ${r.reviewer}` : ""}${r.review_comment ? `: “${r.review_comment}”` : ""}`;
}

export class HistoryPanel {
  readonly el = h("section", { class: "history-panel", "aria-label": "History", "data-testid": "history-panel", hidden: true });
  private readonly list = h("div");
  private readonly compareBox = h("div", { "data-testid": "compare" });
  private readonly msg = h("p", { role: "status", "data-testid": "history-msg" });
  private readonly confirmBox = h("div", { "data-testid": "revert-confirm" });
  private readonly chart = new CorrectionChart(() => undefined);
  private picked: number[] = [];
  private revisions: RevisionPublic[] = [];

  constructor(
    private readonly ctl: EditorController,
    private readonly store: Store<EditorState>,
    private readonly role: string | null,
  ) {
    this.chart.canvas.setAttribute("aria-label", "Distance between the compared revisions along the run");
    this.el.append(
      h("div", { class: "row spread" }, h("h2", {}, "History"), button("×", () => this.close(), { "aria-label": "Close history" })),
      h("p", { class: "muted" }, "Tick two revisions to compare them on the map."),
      this.list, this.compareBox, this.confirmBox, this.msg,
    );
  }

  get isOpen(): boolean {
    return !this.el.hidden;
  }

  toggle(): void {
    if (this.isOpen) this.close();
    else void this.open();
  }

  close(): void {
    this.el.hidden = true;
    this.store.update((s) => (s.compare ? { ...s, compare: null } : s));
  }

  async open(): Promise<void> {
    this.el.hidden = false;
    await this.reload();
  }

  /** Re-read the list (a new revision arrived). */
  async reload(): Promise<void> {
    try {
      const r = await api.listRevisions(this.ctl.runId);
      this.revisions = r.items;
      this.picked = this.picked.filter((n) => r.items.some((x) => x.number === n));
      this.renderList();
    } catch (err) {
      this.msg.textContent = `History failed: ${describeError(err)}`;
    }
  }

  private renderList(): void {
    const head = this.store.get().doc?.revision ?? null;
    const rows = [...this.revisions].reverse().map((r) => {
      const tick = h("input", { type: "checkbox", checked: this.picked.includes(r.number), "aria-label": `Compare revision ${r.number}`, "data-testid": `pick-${r.number}` });
      tick.addEventListener("change", () => this.pick(r.number, tick.checked));
      const mayRevert = MAY_REVERT.has(this.role ?? "") && r.number !== head;
      return h("tr", { "data-testid": `revision-${r.number}` },
        h("td", {}, tick),
        h("td", {}, h("strong", {}, String(r.number)), " ", h("span", { class: "muted" }, r.kind)),
        h("td", {}, r.author ?? "—", h("br"), h("small", { class: "muted" }, fmtTime(r.created_at))),
        h("td", {},
          r.comment ? h("span", { "data-testid": "revision-comment" }, `“${r.comment}”`) : "",
          r.task_id ? h("small", { class: "muted" }, ` task ${r.task_id}`) : "",
          r.review ? h("div", { class: "muted", "data-testid": "revision-review" }, reviewText(r)) : "",
          h("div", { class: "muted" }, `${plural(r.n_moves, "move")}, ${r.n_deleted} deleted`)),
        h("td", {}, mayRevert ? button("Revert to this…", () => void this.askRevert(r.number), { "data-testid": `revert-${r.number}` }) : r.number === head ? h("small", {}, "shown") : ""),
      );
    });
    this.list.replaceChildren(h("table", { class: "table history-table" },
      h("thead", {}, h("tr", {}, h("th", {}, h("span", { class: "sr-only" }, "Compare")), h("th", {}, "Rev"), h("th", {}, "Who, when"), h("th", {}, "What"), h("th", {}, h("span", { class: "sr-only" }, "Revert")))),
      h("tbody", {}, ...rows)));
  }

  private pick(n: number, on: boolean): void {
    this.picked = on ? [...this.picked.filter((x) => x !== n), n].slice(-2) : this.picked.filter((x) => x !== n);
    this.renderList();
    if (this.picked.length === 2) void this.compare(Math.min(...this.picked), Math.max(...this.picked));
    else {
      this.compareBox.replaceChildren();
      this.store.update((s) => (s.compare ? { ...s, compare: null } : s));
    }
  }

  private async compare(from: number, to: number): Promise<void> {
    this.compareBox.replaceChildren(h("p", {}, `Comparing revisions ${from} and ${to}…`));
    try {
      const [d, a, b] = await Promise.all([api.diff(this.ctl.runId, from, to), api.loadDoc(this.ctl.runId, from), api.loadDoc(this.ctl.runId, to)]);
      const cmp: RevisionCompare = {
        from, to,
        fromPositions: a.keyframes.map((k) => k.lonlat),
        toPositions: b.keyframes.map((k) => k.lonlat),
        displacement: d.displacement_m,
        moved: d.keyframes.map((k) => k.index),
      };
      this.store.update((s) => ({ ...s, compare: cmp }));
      this.compareBox.replaceChildren(
        h("h3", {}, `Revision ${from} → ${to}`),
        h("p", { "data-testid": "compare-summary" }, `${plural(d.changed, "keyframe")} moved, up to ${d.max_m.toFixed(1)} m (mean ${d.mean_m.toFixed(2)} m).`),
        h("ul", { class: "legend compare-legend" },
          h("li", {}, h("span", { class: "line-swatch compare-from" }), `Revision ${from}`),
          h("li", {}, h("span", { class: "line-swatch compare-to" }), `Revision ${to} (dots: moved keyframes)`)),
        h("span", { class: "chart-title" }, "Distance between them (m) along the run"),
        this.chart.canvas,
      );
      this.chart.set({ now: d.displacement_m, before: [], selected: null, deleted: [] });
    } catch (err) {
      this.compareBox.replaceChildren(h("p", { class: "error" }, `Compare failed: ${describeError(err)}`));
    }
  }

  private async askRevert(to: number): Promise<void> {
    const s = this.store.get();
    if (!s.doc) return;
    const head = s.doc.revision;
    this.confirmBox.replaceChildren(h("p", {}, "Working out what would change…"));
    let what: string;
    try {
      const d = await api.diff(this.ctl.runId, head, to);
      what = `${plural(d.changed, "keyframe")} will move, up to ${d.max_m.toFixed(1)} m`;
    } catch (err) {
      what = `the change could not be measured (${describeError(err)})`;
    }
    const comment = h("input", { "aria-label": "Why revert (stored with the revision)", placeholder: "Why (optional)" });
    const yes = button(`Revert to revision ${to}`, async () => {
      yes.disabled = true;
      this.confirmBox.replaceChildren();
      this.msg.textContent = `Reverting to revision ${to}…`;
      try {
        await this.ctl.revertTo(to, comment.value);
        this.msg.textContent = `Reverted: revision ${this.store.get().doc?.revision} has the edits of revision ${to}.`;
        await this.reload();
      } catch (err) {
        this.msg.textContent = `Revert refused: ${describeError(err)}`;
      }
    }, { class: "primary", "data-testid": "revert-yes" });
    this.confirmBox.replaceChildren(h("div", { class: "card confirm", role: "alertdialog", "aria-labelledby": "revert-q" },
      h("p", { id: "revert-q", "data-testid": "revert-question" },
        `Revert to revision ${to}? A new revision ${head + 1} gets the edits of revision ${to}; compared with revision ${head} (shown now), ${what}. History is kept, so this can be reverted too.`),
      comment,
      h("div", { class: "row" }, yes, button("Cancel", () => this.confirmBox.replaceChildren(), { "data-testid": "revert-cancel" }))));
    yes.focus();
  }
}
