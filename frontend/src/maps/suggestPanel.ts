/**
 * The editor's "Suggestions" tools: fetch map-matching suggestions into the editor state
 * (the map adapter draws them), accept one (click its point) or all in one click.
 * Accepted suggestions become staged edits through the controller (rules, preview, submit).
 */
import type { Map as MlMap, MapLayerMouseEvent } from "maplibre-gl";
import { describeError } from "../api/errors";
import { SUGGESTION_POINT_LAYER } from "../map/adapter";
import type { EditorController } from "../ui/editor/controller";
import { h, plural } from "../ui/dom";
import { type EditorState, currentEdits, currentSuggestions } from "../state/editor";
import type { SuggestionsState } from "../state/types";
import { jobResult, mapsApi } from "./api";
import { actionAcceptAllSuggestions, actionAcceptSuggestion, pending, suggestionsFrom } from "./suggestions";

export class SuggestionsPanel {
  readonly fetchBtn: HTMLButtonElement;
  readonly acceptAllBtn: HTMLButtonElement;
  readonly info: HTMLElement;
  private unsub: () => void;
  private alive = true;

  constructor(private readonly ctl: EditorController, private readonly notify: (text: string) => void) {
    this.fetchBtn = h("button", { type: "button", "data-testid": "suggestions", title: "Match the run to the street map and suggest positions" }, "Suggestions");
    this.fetchBtn.addEventListener("click", () => void this.fetch());
    this.acceptAllBtn = h("button", { type: "button", "data-testid": "suggestions-accept-all", hidden: true }, "Accept all");
    this.acceptAllBtn.addEventListener("click", () => this.acceptAll());
    this.info = h("span", { class: "suggest-info", "data-testid": "suggestions-info", role: "status" });
    this.unsub = ctl.store.subscribe((s) => this.render(s));
  }

  get elements(): HTMLElement[] {
    return [this.fetchBtn, this.acceptAllBtn, this.info];
  }

  dispose(): void {
    this.alive = false;
    this.unsub();
  }

  private get state(): SuggestionsState {
    return currentSuggestions(this.ctl.store.get());
  }

  private set(state: SuggestionsState): void {
    this.ctl.store.update((s) => ({ ...s, suggestions: state }));
  }

  /** Called once the map has loaded and the adapter has installed the suggestion layers. */
  attach(map: MlMap): void {
    map.on("click", SUGGESTION_POINT_LAYER, (e: MapLayerMouseEvent) => {
      const i = Number(e.features?.[0]?.properties?.i);
      const st = this.state;
      if (st.kind !== "ready" || !Number.isFinite(i)) return;
      const s = st.items.find((x) => x.index === i);
      if (s) {
        this.ctl.perform(actionAcceptSuggestion(s), s.lonlat);
        const r = this.ctl.store.get().refusal;
        this.notify(r ? `Suggestion for keyframe ${i} refused: ${r.message}` : `Accepted the suggestion for keyframe ${i} (${s.moved_m.toFixed(1)} m).`);
      }
    });
    map.on("mouseenter", SUGGESTION_POINT_LAYER, () => (map.getCanvas().style.cursor = "pointer"));
    map.on("mouseleave", SUGGESTION_POINT_LAYER, () => (map.getCanvas().style.cursor = ""));
  }

  async fetch(): Promise<void> {
    const s = this.ctl.store.get();
    if (!s.doc || this.state.kind === "loading") return;
    this.set({ kind: "loading" });
    let next: SuggestionsState;
    try {
      const job = await mapsApi.suggestions(this.ctl.runId);
      const result = await jobResult(job.job_id, (f) => (this.fetchBtn.textContent = `Matching… ${Math.round(f * 100)}%`), () => this.alive);
      next = { kind: "ready", ...suggestionsFrom(result) };
    } catch (err) {
      next = { kind: "error", message: `Suggestions failed: ${describeError(err)}` };
    }
    if (this.alive) this.set(next);
  }

  acceptAll(): void {
    const st = this.state;
    if (st.kind !== "ready") return;
    const todo = pending(st.items, currentEdits(this.ctl.store.get()));
    const action = actionAcceptAllSuggestions(todo);
    this.ctl.perform(action);
    const r = this.ctl.store.get().refusal;
    if (r) this.notify(r.message);
    else this.notify(`Accepted ${plural(todo.length - action.skipped.length, "suggestion")}${action.skipped.length ? `; ${action.skipped.length} left out by the rules (${action.skipped[0].message})` : ""}.`);
  }

  private render(s: EditorState): void {
    const cur = currentSuggestions(s);
    this.fetchBtn.disabled = cur.kind === "loading" || !s.doc;
    if (cur.kind !== "loading") this.fetchBtn.textContent = "Suggestions";
    else if (!this.fetchBtn.textContent?.startsWith("Matching")) this.fetchBtn.textContent = "Matching…";
    const todo = cur.kind === "ready" ? pending(cur.items, currentEdits(s)) : [];
    this.acceptAllBtn.hidden = cur.kind !== "ready";
    this.acceptAllBtn.disabled = todo.length === 0;
    this.acceptAllBtn.textContent = `Accept all (${todo.length})`;
    this.info.textContent =
      cur.kind === "error" ? cur.message
        : cur.kind === "ready" ? `${todo.length} suggestion${todo.length === 1 ? "" : "s"} · ${cur.offRoad} off-road keyframe${cur.offRoad === 1 ? "" : "s"}`
          : "";
    this.info.className = `suggest-info ${cur.kind === "error" ? "error" : ""}`;
  }
}
