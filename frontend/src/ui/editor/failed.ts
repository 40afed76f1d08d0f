/**
 * The failed-edit notice: the run's latest batch could not be computed (its job died), so the
 * run stayed at its previous revision. Its author, a reviewer or an admin may retry the batch
 * (the same edits, computed again) or discard it; the server refuses others with a message.
 */
import { api } from "../../api/endpoints";
import { describeError } from "../../api/errors";
import { h } from "../dom";
import { button } from "./toolbar";

export class FailedEditNotice {
  readonly el = h("div", { class: "error-box failed-edit", role: "alert", "data-testid": "failed-edit", hidden: true });

  constructor(private readonly runId: string, private readonly notify: (text: string) => void) {}

  async refresh(): Promise<void> {
    const run = await api.getRun(this.runId);
    const f = run.failed_edit;
    this.el.hidden = !f;
    if (!f) {
      this.el.replaceChildren();
      return;
    }
    this.el.replaceChildren(
      h("p", {}, `Revision ${f.revision} could not be computed, so the run stays at revision ${run.revision}. Why: ${f.error ?? "its job stopped"}.`),
      button("Retry", () => void this.act("retry", f.batch_id), { "data-testid": "failed-retry" }),
      " ",
      button("Discard", () => void this.act("discard", f.batch_id), { "data-testid": "failed-discard" }),
    );
  }

  private async act(what: "retry" | "discard", batchId: number): Promise<void> {
    try {
      if (what === "retry") {
        const r = await api.retryBatch(this.runId, batchId);
        this.notify(`Revision ${r.revision} is being computed again.`);
      } else {
        await api.discardBatch(this.runId, batchId);
        this.notify("The failed edits were discarded.");
      }
    } catch (err) {
      this.notify(`Could not ${what} the failed edits: ${describeError(err)}`);
    }
    await this.refresh();
  }
}
