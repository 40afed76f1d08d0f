/**
 * The editor's controller: loads a run, commits edits (rules first, then the server preview),
 * submits, handles conflicts, and keeps unsaved edits in localStorage so that nothing the
 * operator did is lost on a failed submit or a reload. No DOM, no MapLibre here.
 */
import { api } from "../../api/endpoints";
import { ApiError, describeError } from "../../api/errors";
import { editsBody, editsFromBody } from "../../api/convert";
import { loadDoc, perform, redo, setError, setPreview, undo } from "../../actions/editor";
import { type EditAction, actionMarkDeleted, actionMoveKeyframe } from "../../actions/edits";
import { checkBatch } from "../../rules/apply";
import { type EditorState, currentEdits, editCount, editorNew } from "../../state/editor";
import { Store } from "../../state/store";
import { plural } from "../dom";
import type { Edits, LonLat, RunDoc } from "../../state/types";

const PREVIEW_DEBOUNCE_MS = 60;
const JOB_POLL_MS = 400;
const JOB_TIMEOUT_MS = 120_000;

interface SavedEdits {
  base_revision: number;
  body: ReturnType<typeof editsBody>;
}

export class EditorController {
  readonly store = new Store<EditorState>(editorNew());
  private previewAbort: AbortController | null = null;
  private previewTimer: number | undefined;
  private disposed = false;
  private unsub: () => void;
  private events: EventSource | null = null;
  /** Messages for the operator (refusals of re-applied edits, submit results). */
  onNotice: (text: string) => void = () => {};
  /** Set by a task page: submit to the assignment instead of the run (resolves to a notice). */
  submitTo: ((doc: RunDoc, edits: Edits, comment: string) => Promise<string>) | null = null;

  constructor(readonly runId: string) {
    this.unsub = this.store.subscribe((next, prev) => {
      if (currentEdits(next) !== currentEdits(prev) || next.doc !== prev.doc) {
        this.persist(next);
        this.schedulePreview();
      }
    });
  }

  /**
   * Follow the server's events for this run: when someone else's revision becomes ready,
   * load it at once if nothing is unsaved, else say so (submitting would conflict).
   */
  watch(): void {
    if (typeof EventSource === "undefined" || this.events) return;
    this.events = new EventSource(api.runEventsUrl(this.runId), { withCredentials: true });
    this.events.addEventListener("revision.ready", (ev) => {
      try {
        const d = JSON.parse((ev as MessageEvent).data) as { run_id: number; revision: number };
        void this.revisionReady(Number(d.revision));
      } catch {
        /* a malformed event is ignored; submit still detects conflicts */
      }
    });
  }

  private async revisionReady(n: number): Promise<void> {
    const s = this.store.get();
    if (!s.doc || n <= s.doc.revision || (s.newer !== null && n <= s.newer)) return;
    if (s.submit.kind === "sending" || s.submit.kind === "waiting") return; // our own batch
    if (editCount(currentEdits(s)) === 0 && !s.staging && s.mode === "browse") {
      try {
        const doc = await api.loadDoc(this.runId);
        this.store.update((x) => (editCount(currentEdits(x)) === 0 ? loadDoc(x, doc) : { ...x, newer: n }));
        this.onNotice(`Revision ${doc.revision} was saved by someone else and is now shown.`);
      } catch (err) {
        this.store.update((x) => setError(x, `Loading revision ${n} failed: ${describeError(err)}`));
      }
      return;
    }
    this.store.update((x) => ({ ...x, newer: n }));
  }

  dispose(): void {
    this.disposed = true;
    this.events?.close();
    this.unsub();
    this.previewAbort?.abort();
    window.clearTimeout(this.previewTimer);
  }

  get storageKey(): string {
    return `posefix.unsaved.${this.runId}`;
  }

  /** Load the run's current revision; restore unsaved edits kept from an earlier visit. */
  async load(): Promise<void> {
    let doc: RunDoc;
    try {
      doc = await api.loadDoc(this.runId);
    } catch (err) {
      this.store.update((s) => setError(s, describeError(err)));
      throw err;
    }
    const saved = this.saved();
    if (saved && saved.base_revision === doc.revision) {
      this.store.update((s) => loadDoc(s, doc, { label: "Restore unsaved edits", edits: editsFromBody(saved.body) }));
      this.onNotice(`Restored ${plural(editCount(currentEdits(this.store.get())), "unsaved edit")} from your last visit.`);
    } else if (saved && editCount(editsFromBody(saved.body)) > 0) {
      // Unsaved work made against an older revision: same screen as a stale submit.
      this.store.update((s) => ({
        ...loadDoc(s, doc, { label: "Restore unsaved edits", edits: editsFromBody(saved.body) }),
        conflict: { baseRevision: saved.base_revision, currentRevision: doc.revision },
      }));
    } else {
      this.store.update((s) => loadDoc(s, doc));
    }
  }

  /** A drag ended: one labelled step if the rules allow it, else the refusal where it was dropped. */
  commitMove(index: number, lonlat: LonLat): void {
    this.perform(actionMoveKeyframe(index, lonlat), lonlat);
  }

  commitRange(from: number, to: number): void {
    this.perform(actionMarkDeleted(from, to));
  }

  perform(action: EditAction, at?: LonLat): void {
    this.store.update((s) => perform(s, action, at));
  }

  undo(): void {
    this.store.update(undo);
  }

  redo(): void {
    this.store.update(redo);
  }

  private schedulePreview(): void {
    window.clearTimeout(this.previewTimer);
    this.previewAbort?.abort();
    const s = this.store.get();
    if (!s.doc || s.conflict) return;
    const edits = currentEdits(s);
    if (edits.moves.size === 0 && edits.deleted.size === 0) {
      if (s.preview || s.previewPending) this.store.update((x) => ({ ...x, preview: null, previewPending: false }));
      return;
    }
    this.store.update((x) => (x.previewPending ? x : { ...x, previewPending: true }));
    this.previewTimer = window.setTimeout(() => void this.runPreview(s.doc!, edits), PREVIEW_DEBOUNCE_MS);
  }

  private async runPreview(doc: RunDoc, edits: Edits): Promise<void> {
    const abort = new AbortController();
    this.previewAbort = abort;
    try {
      const r = await api.preview(doc.runId, doc.revision, edits, abort.signal);
      if (this.disposed || abort.signal.aborted) return;
      const s = this.store.get();
      if (currentEdits(s) !== edits) return;
      if (r.refusals.length > 0) {
        // The server refused what the browser allowed: show why, and take the step back.
        const first = r.refusals[0];
        this.store.update((x) => {
          const back = undo(x);
          return { ...back, previewPending: false, refusal: { ...first, at: edits.moves.get(first.index) ?? doc.keyframes[first.index]?.lonlat ?? [0, 0] } };
        });
        return;
      }
      if (r.positions.length !== doc.keyframes.length) {
        this.store.update((x) => setError(x, `The preview returned ${r.positions.length} positions for ${doc.keyframes.length} keyframes.`));
        return;
      }
      this.store.update((x) => setPreview(x, edits, r.positions, r.solverTimeS, r.drift, r.flags));
      if (r.flags.length) this.onNotice(`Accepted with a flag: ${r.flags.map((f) => f.message).join(" ")}`);
    } catch (err) {
      if (abort.signal.aborted || (err instanceof DOMException && err.name === "AbortError")) return;
      if (err instanceof ApiError && err.status === 409) {
        const cur = Number(err.body.current_revision);
        this.store.update((x) => ({ ...x, previewPending: false, conflict: { baseRevision: doc.revision, currentRevision: Number.isFinite(cur) ? cur : null } }));
        return;
      }
      this.store.update((x) => setError(x, `Preview failed: ${describeError(err)}`));
    }
  }

  /** Send every unsaved edit in one call; wait for the new revision; keep edits on failure. */
  async submit(comment = ""): Promise<void> {
    const s = this.store.get();
    if (!s.doc || s.submit.kind === "sending" || s.submit.kind === "waiting") return;
    const edits = currentEdits(s);
    if (editCount(edits) === 0) {
      this.store.update((x) => ({ ...x, submit: { kind: "error", message: "Nothing to submit: move, delete or accept first." } }));
      return;
    }
    const doc = s.doc;
    this.store.update((x) => ({ ...x, submit: { kind: "sending" }, error: null }));
    if (this.submitTo) {
      try {
        const notice = await this.submitTo(doc, edits, comment);
        localStorage.removeItem(this.storageKey);
        // The submission holds the edits now: the editor shows nothing unsaved.
        this.store.update((x) => ({ ...loadDoc(x, doc), submit: { kind: "idle" } }));
        this.onNotice(notice);
      } catch (err) {
        this.submitFailed(err, doc);
      }
      return;
    }
    let jobId: string;
    try {
      const r = await api.submitEdits(doc.runId, doc.revision, edits, comment);
      jobId = String(r.job_id);
    } catch (err) {
      this.submitFailed(err, doc);
      return;
    }
    await this.awaitRevision(jobId, (rev) => `Submitted. Revision ${rev} is ready.`);
  }

  /** Follow the correction job of an accepted batch; load its revision when it is ready. */
  private async awaitRevision(jobId: string, notice: (revision: number) => string): Promise<void> {
    this.store.update((x) => ({ ...x, submit: { kind: "waiting", jobId, progress: 0 } }));
    const t0 = Date.now();
    try {
      for (;;) {
        if (this.disposed) return;
        const job = await api.getJob(jobId);
        const status = String(job.status);
        if (["done", "succeeded", "success", "completed", "complete"].includes(status)) break;
        if (["failed", "dead", "error", "cancelled"].includes(status)) {
          throw new Error(`the correction job ${status}${job.last_error ? `: ${job.last_error}` : ""}`);
        }
        this.store.update((x) => ({ ...x, submit: { kind: "waiting", jobId, progress: Number(job.progress ?? 0) } }));
        if (Date.now() - t0 > JOB_TIMEOUT_MS) throw new Error("the correction job is taking long; your edits were received, reload later");
        await new Promise((r) => setTimeout(r, JOB_POLL_MS));
      }
      const next = await api.loadDoc(this.runId);
      localStorage.removeItem(this.storageKey);
      this.store.update((x) => ({ ...loadDoc(x, next), submit: { kind: "done", revision: next.revision } }));
      this.onNotice(notice(next.revision));
    } catch (err) {
      // The batch was accepted by the server; what failed is waiting for its result.
      this.store.update((x) => ({ ...x, submit: { kind: "error", message: `Submitted, but: ${describeError(err)}` } }));
    }
  }

  /**
   * Make a new revision with the edits of revision `to` (history is kept). Refused while
   * there are unsaved edits: they were made against the shown revision.
   */
  async revertTo(to: number, comment: string): Promise<void> {
    const s = this.store.get();
    if (!s.doc || s.submit.kind === "sending" || s.submit.kind === "waiting") return;
    if (editCount(currentEdits(s)) > 0) throw new Error("Submit or reset your unsaved edits before reverting.");
    this.store.update((x) => ({ ...x, submit: { kind: "sending" }, error: null }));
    let jobId: string;
    try {
      jobId = String((await api.revert(this.runId, to, s.doc.revision, comment)).job_id);
    } catch (err) {
      this.store.update((x) => ({ ...x, submit: { kind: "idle" } }));
      throw err;
    }
    await this.awaitRevision(jobId, (rev) => `Reverted to revision ${to}: revision ${rev} is ready.`);
  }

  private submitFailed(err: unknown, doc: RunDoc): void {
    if (err instanceof ApiError && err.status === 409) {
      const cur = Number(err.body.current_revision);
      this.store.update((x) => ({ ...x, submit: { kind: "idle" }, conflict: { baseRevision: doc.revision, currentRevision: Number.isFinite(cur) ? cur : null } }));
      return;
    }
    if (err instanceof ApiError && err.status === 422 && Array.isArray(err.body.refusals) && err.body.refusals.length) {
      const first = err.body.refusals[0] as { index: number; reason: string; message: string };
      const at = currentEdits(this.store.get()).moves.get(first.index) ?? doc.keyframes[first.index]?.lonlat ?? [0, 0];
      this.store.update((x) => ({ ...x, submit: { kind: "error", message: `The server refused the edits: ${first.message}` }, refusal: { ...first, at } }));
      return;
    }
    this.store.update((x) => ({ ...x, submit: { kind: "error", message: `Submit failed: ${describeError(err)} Your edits are kept.` } }));
  }

  /** After a conflict: load the latest revision and re-apply the unsaved edits that still pass. */
  async reloadAndReapply(): Promise<void> {
    const edits = currentEdits(this.store.get());
    const want = this.store.get().conflict?.currentRevision ?? this.store.get().newer ?? null;
    let doc: RunDoc;
    try {
      doc = await this.loadAtLeast(want);
    } catch (err) {
      this.store.update((s) => setError(s, `Reload failed: ${describeError(err)}`));
      return;
    }
    const check = checkBatch(doc, edits);
    const refused = new Set(check.refusals.map((r) => r.index));
    const moves = new Map([...edits.moves].filter(([i]) => !refused.has(i) && i < doc.keyframes.length));
    const deleted = new Set([...edits.deleted].filter((i) => i < doc.keyframes.length));
    const kept: Edits = { moves, deleted, accept: edits.accept };
    this.store.update((s) => loadDoc(s, doc, editCount(kept) ? { label: "Re-apply unsaved edits", edits: kept } : undefined));
    this.onNotice(
      check.refusals.length
        ? `Reloaded revision ${doc.revision}. ${plural(check.refusals.length, "edit")} no longer ${check.refusals.length === 1 ? "passes" : "pass"} the rules and ${check.refusals.length === 1 ? "was" : "were"} dropped: ${check.refusals.map((r) => r.message).join(" ")}`
        : `Reloaded revision ${doc.revision} and re-applied ${plural(editCount(kept), "unsaved edit")}.`,
    );
  }

  /**
   * Load the run, waiting (up to a minute) while the revision that caused a conflict is
   * still being computed by the worker, so re-applied edits land on top of it.
   */
  private async loadAtLeast(revision: number | null): Promise<RunDoc> {
    const t0 = Date.now();
    for (;;) {
      const doc = await api.loadDoc(this.runId);
      if (revision === null || doc.revision >= revision || Date.now() - t0 > JOB_TIMEOUT_MS / 2) return doc;
      this.onNotice(`Waiting for revision ${revision} to be computed…`);
      await new Promise((r) => setTimeout(r, JOB_POLL_MS * 2));
    }
  }

  /** After a conflict: drop the unsaved edits and load the latest revision. */
  async reloadDiscarding(): Promise<void> {
    localStorage.removeItem(this.storageKey);
    try {
      const doc = await api.loadDoc(this.runId);
      this.store.update((s) => loadDoc(s, doc));
    } catch (err) {
      this.store.update((s) => setError(s, `Reload failed: ${describeError(err)}`));
    }
  }

  private persist(s: EditorState): void {
    if (!s.doc || s.conflict) return;
    const e = currentEdits(s);
    try {
      if (editCount(e) === 0) localStorage.removeItem(this.storageKey);
      else localStorage.setItem(this.storageKey, JSON.stringify({ base_revision: s.doc.revision, body: editsBody(e) } satisfies SavedEdits));
    } catch {
      /* storage full or disabled: edits stay in memory */
    }
  }

  private saved(): SavedEdits | null {
    try {
      const raw = localStorage.getItem(this.storageKey);
      return raw ? (JSON.parse(raw) as SavedEdits) : null;
    } catch {
      return null;
    }
  }
}
