/**
 * The editor's "Suggestions" tools: fetch map-matching suggestions into the editor state
 * (the map adapter draws them), pick one (a click on its point or its row: never an
 * accept), then accept or skip it with a button or a key, or accept all in one click.
 * Accepted suggestions become staged edits through the controller (rules, preview, submit).
 */
import type { Map as MlMap, MapLayerMouseEvent } from "maplibre-gl";
import { select } from "../actions/editor";
import { describeError } from "../api/errors";
import { SUGGESTION_POINT_LAYER } from "../map/adapter";
import type { EditorController } from "../ui/editor/controller";
import { h, plural } from "../ui/dom";
import { type EditorState, currentEdits, currentSuggestions } from "../state/editor";
import type { Edits, SuggestionsReady, SuggestionsState } from "../state/types";
import { jobResult, mapsApi } from "./api";
import {
  actionAcceptAllSuggestions, actionAcceptSuggestion, focusAfterAccept, focusSuggestion, focused, listed, pending,
  skipSuggestion, stepSuggestion, suggestionsFrom, suggestionsReady, todo, toggleSuggestionsShown,
} from "./suggestions";

export class SuggestionsPanel {
  /** Fetches the suggestions; once they are here, shows or hides them. */
  readonly fetchBtn: HTMLButtonElement;
  readonly acceptAllBtn: HTMLButtonElement;
  /** Loading progress and errors, beside the button. */
  readonly error: HTMLElement;
  private readonly info: HTMLElement;
  /** The side panel's list: the focused suggestion with Accept / Skip, and every suggestion. */
  readonly listEl: HTMLElement;
  private readonly current = h("p", { "data-testid": "suggestion-current" });
  private readonly acceptBtn: HTMLButtonElement;
  private readonly skipBtn: HTMLButtonElement;
  private readonly rows = h("ol", { class: "suggest-list", "data-testid": "suggestion-list", "aria-label": "Suggestions" });
  private unsub: () => void;
  private alive = true;
  private lastRows: unknown[] = [];

  constructor(private readonly ctl: EditorController, private readonly notify: (text: string) => void) {
    this.fetchBtn = h("button", { type: "button", "data-testid": "suggestions", title: "Match the run to the street map and suggest positions" }, "Suggestions");
    this.fetchBtn.addEventListener("click", () => (this.ready ? this.toggle() : void this.fetch()));
    this.acceptAllBtn = h("button", { type: "button", "data-testid": "suggestions-accept-all" }, "Accept all");
    this.acceptAllBtn.addEventListener("click", () => this.acceptAll());
    this.error = h("span", { class: "suggest-info", "data-testid": "suggestions-error", role: "status" });
    this.info = h("p", { class: "muted", "data-testid": "suggestions-info" });
    this.acceptBtn = h("button", { type: "button", class: "primary", "data-testid": "suggestion-accept", title: "Accept the picked suggestion (Enter)" }, "Accept");
    this.acceptBtn.addEventListener("click", () => this.acceptFocused());
    this.skipBtn = h("button", { type: "button", "data-testid": "suggestion-skip", title: "Pass over it and pick the next (S)" }, "Skip");
    this.skipBtn.addEventListener("click", () => this.skip());
    this.listEl = h("section", { class: "suggest-panel", "aria-label": "Suggestions", "data-testid": "suggestion-panel", hidden: true },
      h("h2", {}, "Suggestions"),
      this.info,
      this.current,
      h("div", { class: "row" }, this.acceptBtn, this.skipBtn, this.acceptAllBtn),
      h("p", { class: "muted keys-hint" }, h("kbd", {}, "Enter"), " accept · ", h("kbd", {}, "S"), " skip · ", h("kbd", {}, "["), " / ", h("kbd", {}, "]"), " previous / next"),
      this.rows);
    this.unsub = ctl.store.subscribe((s) => this.render(s));
  }

  get elements(): HTMLElement[] {
    return [this.fetchBtn, this.error];
  }

  dispose(): void {
    this.alive = false;
    this.unsub();
  }

  private get ready(): SuggestionsReady | null {
    const st = currentSuggestions(this.ctl.store.get());
    return st.kind === "ready" ? st : null;
  }

  private set(state: SuggestionsState): void {
    this.ctl.store.update((s) => ({ ...s, suggestions: state }));
  }

  /** Change the shown suggestions and select the focused one's keyframe (the map follows). */
  private update(f: (st: SuggestionsReady) => SuggestionsReady): void {
    this.ctl.store.update((s) => {
      const st = currentSuggestions(s);
      if (st.kind !== "ready") return s;
      const next = f(st);
      return next.focus !== null && next.focus !== st.focus ? select({ ...s, suggestions: next }, next.focus) : { ...s, suggestions: next };
    });
  }

  /** Called once the map has loaded and the adapter has installed the suggestion layers. */
  attach(map: MlMap): void {
    map.on("click", SUGGESTION_POINT_LAYER, (e: MapLayerMouseEvent) => {
      const i = Number(e.features?.[0]?.properties?.i);
      if (Number.isFinite(i)) this.focus(i);
    });
    map.on("mouseenter", SUGGESTION_POINT_LAYER, () => (map.getCanvas().style.cursor = "pointer"));
    map.on("mouseleave", SUGGESTION_POINT_LAYER, () => (map.getCanvas().style.cursor = ""));
  }

  /** Whether the suggestion keys apply now (suggestions on the map). */
  get active(): boolean {
    return this.ready?.shown === true;
  }

  focus(i: number): void {
    this.update((st) => focusSuggestion(st, i));
  }

  step(d: 1 | -1): void {
    this.update((st) => stepSuggestion(st, d));
  }

  skip(): void {
    const st = this.ready;
    if (!st || st.focus === null) return;
    const i = st.focus;
    this.update((x) => skipSuggestion(x, currentEdits(this.ctl.store.get())));
    this.notify(`Skipped the suggestion for keyframe ${i}.`);
  }

  toggle(): void {
    this.update(toggleSuggestionsShown);
  }

  acceptFocused(): void {
    const st = this.ready;
    const s = st ? focused(st) : null;
    if (!st || !s) {
      this.notify("Pick a suggestion first: click its point or its row.");
      return;
    }
    this.ctl.perform(actionAcceptSuggestion(s), s.lonlat);
    const r = this.ctl.store.get().refusal;
    if (r) {
      this.notify(`Suggestion for keyframe ${s.index} refused: ${r.message}`);
      return;
    }
    this.update((x) => focusAfterAccept(x, currentEdits(this.ctl.store.get())));
    this.notify(`Accepted the suggestion for keyframe ${s.index} (${s.moved_m.toFixed(1)} m).`);
  }

  async fetch(): Promise<void> {
    const s = this.ctl.store.get();
    if (!s.doc || currentSuggestions(s).kind === "loading") return;
    this.set({ kind: "loading" });
    let next: SuggestionsState;
    try {
      const job = await mapsApi.suggestions(this.ctl.runId);
      const result = await jobResult(job.job_id, (f) => (this.fetchBtn.textContent = `Matching… ${Math.round(f * 100)}%`), () => this.alive);
      next = suggestionsReady(suggestionsFrom(result), currentEdits(this.ctl.store.get()));
    } catch (err) {
      next = { kind: "error", message: `Suggestions failed: ${describeError(err)}` };
    }
    if (this.alive) {
      this.set(next);
      if (next.kind === "ready" && next.focus !== null) this.ctl.store.update((x) => select(x, next.focus));
    }
  }

  acceptAll(): void {
    const st = this.ready;
    if (!st) return;
    const left = todo(st, currentEdits(this.ctl.store.get()));
    const action = actionAcceptAllSuggestions(left);
    this.ctl.perform(action);
    const r = this.ctl.store.get().refusal;
    if (r) this.notify(r.message);
    else {
      this.update((x) => focusAfterAccept(x, currentEdits(this.ctl.store.get())));
      this.notify(`Accepted ${plural(left.length - action.skipped.length, "suggestion")}${action.skipped.length ? `; ${action.skipped.length} left out by the rules (${action.skipped[0].message})` : ""}.`);
    }
  }

  private render(s: EditorState): void {
    const cur = currentSuggestions(s);
    this.fetchBtn.disabled = cur.kind === "loading" || !s.doc;
    if (cur.kind !== "loading") this.fetchBtn.textContent = "Suggestions";
    else if (!this.fetchBtn.textContent?.startsWith("Matching")) this.fetchBtn.textContent = "Matching…";
    const ready = cur.kind === "ready" ? cur : null;
    const edits = currentEdits(s);
    const left = ready ? todo(ready, edits) : [];
    if (ready) this.fetchBtn.setAttribute("aria-pressed", String(ready.shown));
    else this.fetchBtn.removeAttribute("aria-pressed");
    this.fetchBtn.title = ready ? "Show or hide the suggestions on the map" : "Match the run to the street map and suggest positions";
    this.acceptAllBtn.disabled = left.length === 0;
    this.acceptAllBtn.textContent = `Accept all (${left.length})`;
    this.info.textContent = ready ? `${plural(left.length, "suggestion")} to decide · ${plural(ready.offRoad, "off-road keyframe")} · ${ready.matcher === "grid" ? "drivable-area grid" : "road network"}` : "";
    this.error.textContent = cur.kind === "error" ? cur.message : "";
    this.error.className = `suggest-info ${cur.kind === "error" ? "error" : ""}`;
    this.listEl.hidden = !ready?.shown;
    if (ready?.shown) this.renderList(ready, edits);
  }

  private renderList(st: SuggestionsReady, edits: Edits): void {
    const f = focused(st);
    this.acceptBtn.disabled = !f || !!edits.suggested?.has(f.index);
    this.skipBtn.disabled = !f;
    this.current.textContent = f
      ? `Keyframe ${f.index}: move ${f.moved_m.toFixed(1)} m onto the street${f.off_road ? " (now off-road)" : ""}${edits.suggested?.has(f.index) ? " · accepted" : st.skipped.has(f.index) ? " · skipped" : ""}.`
      : "Every suggestion is decided. Click a point or a row to look at one again.";
    const deps = [st.items, st.focus, st.skipped, edits];
    if (deps.every((d, i) => d === this.lastRows[i])) return;
    this.lastRows = deps;
    const accepted = new Set(pending(st.items, edits).map((x) => x.index));
    this.rows.replaceChildren(...listed(st).map((x) => {
      const state = !accepted.has(x.index) ? "accepted" : st.skipped.has(x.index) ? "skipped" : "to decide";
      const b = h("button", { type: "button", class: "link", "data-testid": `suggestion-row-${x.index}`, "aria-current": x.index === st.focus ? "true" : undefined },
        `#${x.index} · ${x.moved_m.toFixed(1)} m${x.off_road ? " · off-road" : ""} · ${state}`);
      b.addEventListener("click", () => this.focus(x.index));
      return h("li", { "data-state": state }, b);
    }));
    this.rows.querySelector("[aria-current=true]")?.scrollIntoView({ block: "nearest" });
  }
}
