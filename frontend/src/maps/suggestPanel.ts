/**
 * The editor's "Suggestions" tools: fetch map-matching suggestions, draw them as their own
 * dashed layer, flag off-road keyframes, accept one (click its point) or all in one click.
 * Accepted suggestions become staged edits through the controller (rules, preview, submit).
 */
import type { GeoJSONSource, Map as MlMap, MapLayerMouseEvent } from "maplibre-gl";
import { describeError } from "../api/errors";
import type { EditorController } from "../ui/editor/controller";
import { h } from "../ui/dom";
import { type EditorState, currentEdits, displayPositions } from "../state/editor";
import { jobResult, mapsApi } from "./api";
import { type SuggestionsState, actionAcceptAllSuggestions, actionAcceptSuggestion, pending, suggestionsFC, suggestionsFrom } from "./suggestions";

const SOURCE = "pf-suggestions";
const POINT_LAYER = "pf-sug-point";
const COLOR = "#d97706"; // amber: machine suggestions, distinct from the operator's blues

export class SuggestionsPanel {
  readonly fetchBtn: HTMLButtonElement;
  readonly acceptAllBtn: HTMLButtonElement;
  readonly info: HTMLElement;
  private state: SuggestionsState = { kind: "idle" };
  private map: MlMap | null = null;
  private unsub: () => void;
  private lastKey: unknown[] = [];
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
    this.map = null;
  }

  /** Called once the map has loaded (and again after a basemap switch re-creates layers). */
  attach(map: MlMap): void {
    this.map = map;
    this.install();
    map.on("styledata", () => this.install());
    map.on("click", POINT_LAYER, (e: MapLayerMouseEvent) => {
      const i = Number(e.features?.[0]?.properties?.i);
      if (this.state.kind !== "ready" || !Number.isFinite(i)) return;
      const s = this.state.items.find((x) => x.index === i);
      if (s) {
        this.ctl.perform(actionAcceptSuggestion(s), s.lonlat);
        const r = this.ctl.store.get().refusal;
        this.notify(r ? `Suggestion for keyframe ${i} refused: ${r.message}` : `Accepted the suggestion for keyframe ${i} (${s.moved_m.toFixed(1)} m).`);
      }
    });
    map.on("mouseenter", POINT_LAYER, () => (map.getCanvas().style.cursor = "pointer"));
    map.on("mouseleave", POINT_LAYER, () => (map.getCanvas().style.cursor = ""));
  }

  private install(): void {
    const m = this.map;
    // After "load" the style exists even while tile sources are still loading.
    if (!m || m.getSource(SOURCE)) return;
    m.addSource(SOURCE, { type: "geojson", data: { type: "FeatureCollection", features: [] } });
    m.addLayer({ id: "pf-sug-path", type: "line", source: SOURCE, filter: ["==", ["get", "kind"], "path"], paint: { "line-color": COLOR, "line-width": 2, "line-opacity": 0.7, "line-dasharray": [3, 2] } });
    m.addLayer({ id: "pf-sug-link", type: "line", source: SOURCE, filter: ["==", ["get", "kind"], "link"], paint: { "line-color": COLOR, "line-width": 1.5, "line-dasharray": [1, 1.5] } });
    m.addLayer({ id: "pf-sug-offroad", type: "circle", source: SOURCE, filter: ["==", ["get", "kind"], "offroad"], paint: { "circle-radius": 11, "circle-color": "rgba(0,0,0,0)", "circle-stroke-color": "#b91c1c", "circle-stroke-width": 2 } });
    m.addLayer({
      id: POINT_LAYER, type: "circle", source: SOURCE, filter: ["==", ["get", "kind"], "point"],
      paint: { "circle-radius": 6, "circle-color": ["case", ["get", "accepted"], COLOR, "#ffffff"], "circle-stroke-color": COLOR, "circle-stroke-width": 2.5 },
    });
    this.lastKey = [];
    this.render(this.ctl.store.get());
  }

  async fetch(): Promise<void> {
    const s = this.ctl.store.get();
    if (!s.doc || this.state.kind === "loading") return;
    this.state = { kind: "loading" };
    this.render(s, true);
    try {
      const job = await mapsApi.suggestions(this.ctl.runId);
      const result = await jobResult(job.job_id, (f) => (this.fetchBtn.textContent = `Matching… ${Math.round(f * 100)}%`), () => this.alive);
      const r = suggestionsFrom(result);
      this.state = { kind: "ready", ...r };
    } catch (err) {
      this.state = { kind: "error", message: `Suggestions failed: ${describeError(err)}` };
    }
    this.render(this.ctl.store.get(), true);
  }

  acceptAll(): void {
    if (this.state.kind !== "ready") return;
    const todo = pending(this.state.items, currentEdits(this.ctl.store.get()));
    const action = actionAcceptAllSuggestions(todo);
    this.ctl.perform(action);
    const r = this.ctl.store.get().refusal;
    if (r) this.notify(r.message);
    else this.notify(`Accepted ${todo.length - action.skipped.length} suggestions${action.skipped.length ? `; ${action.skipped.length} left out by the rules (${action.skipped[0].message})` : ""}.`);
  }

  private render(s: EditorState, force = false): void {
    const st = this.state;
    // Suggestions are for the revision they were computed on.
    if (st.kind === "ready" && s.doc && s.doc.revision !== st.revision) this.state = { kind: "idle" };
    const cur = this.state;
    this.fetchBtn.disabled = cur.kind === "loading" || !s.doc;
    this.fetchBtn.textContent = cur.kind === "loading" ? "Matching…" : "Suggestions";
    const todo = cur.kind === "ready" ? pending(cur.items, currentEdits(s)) : [];
    this.acceptAllBtn.hidden = cur.kind !== "ready";
    this.acceptAllBtn.disabled = todo.length === 0;
    this.acceptAllBtn.textContent = `Accept all (${todo.length})`;
    this.info.textContent =
      cur.kind === "error" ? cur.message
        : cur.kind === "ready" ? `${todo.length} suggestion${todo.length === 1 ? "" : "s"} · ${cur.offRoad} off-road keyframe${cur.offRoad === 1 ? "" : "s"}`
          : "";
    this.info.className = `suggest-info ${cur.kind === "error" ? "error" : ""}`;
    const key = [cur, s.doc, currentEdits(s), s.preview];
    if (!force && key.every((k, i) => k === this.lastKey[i])) return;
    this.lastKey = key;
    const src = this.map?.getSource(SOURCE) as GeoJSONSource | undefined;
    if (!src) return;
    src.setData(cur.kind === "ready" ? suggestionsFC(cur.items, displayPositions(s), currentEdits(s)) : { type: "FeatureCollection", features: [] });
  }
}
