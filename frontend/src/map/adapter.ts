/**
 * The map adapter: the only code that turns editor state into MapLibre sources and layers.
 * It never changes state; on each store change it calls `source.setData` for just the
 * sources whose inputs changed (while dragging, only the tiny staging source), so 10,000
 * keyframes stay smooth.
 */
import type { GeoJSONSource, Map as MlMap } from "maplibre-gl";
import { type EditorState, currentEdits, currentSuggestions, displayPositions } from "../state/editor";
import { suggestionsFC } from "../maps/suggestions";
import {
  type FC,
  OFFROAD_COLOR,
  STATUS_COLORS,
  SUGGESTION_COLOR,
  compareFC,
  emptyFC,
  ghostFC,
  keyframesFC,
  refusalFC,
  selectionFC,
  stagingFC,
  trackFC,
} from "./features";
import { arrowIcon, chevronIcon } from "./icons";

export const KEYFRAME_LAYER = "pf-kf-hit";
export const SUGGESTION_POINT_LAYER = "pf-sug-point";
/** Revisions compared in the history panel: the older dashed teal, the newer violet. */
export const COMPARE_FROM = "#0d9488";
export const COMPARE_TO = "#7c3aed";
function suggestionLayerFC(s: EditorState): FC {
  const g = currentSuggestions(s);
  return g.kind === "ready" && g.shown ? suggestionsFC(g.items, displayPositions(s), currentEdits(s), 0.5, g.focus) : emptyFC();
}

interface SourceSpec {
  id: string;
  deps: (s: EditorState) => unknown[];
  build: (s: EditorState) => FC;
}

const SOURCES: SourceSpec[] = [
  { id: "pf-ghost", deps: (s) => [s.doc, s.showGhost], build: ghostFC },
  { id: "pf-track", deps: (s) => [s.doc, currentEdits(s), s.preview], build: trackFC },
  { id: "pf-keyframes", deps: (s) => [s.doc, currentEdits(s), s.preview], build: keyframesFC },
  { id: "pf-selection", deps: (s) => [s.doc, currentEdits(s), s.preview, s.selected, s.rangeAnchor], build: selectionFC },
  { id: "pf-staging", deps: (s) => [s.doc, s.staging], build: stagingFC },
  { id: "pf-refusal", deps: (s) => [s.refusal], build: refusalFC },
  { id: "pf-compare", deps: (s) => [s.compare], build: compareFC },
  { id: "pf-suggestions", deps: (s) => [currentSuggestions(s), s.doc, currentEdits(s), s.preview], build: suggestionLayerFC },
];

const statusColor: unknown[] = ["match", ["get", "s"]];
for (const [k, v] of Object.entries(STATUS_COLORS)) statusColor.push(k, v);
statusColor.push("#64748b");

export class MapAdapter {
  private lastDeps = new Map<string, unknown[]>();
  private hidden: number | null = null;

  constructor(private readonly map: MlMap) {}

  /** Add sources, images and layers (again after a basemap style switch). */
  install(): void {
    const m = this.map;
    if (!m.hasImage("pf-arrow")) m.addImage("pf-arrow", arrowIcon(), { sdf: true, pixelRatio: 2 });
    if (!m.hasImage("pf-chevron")) m.addImage("pf-chevron", chevronIcon(), { sdf: true, pixelRatio: 2 });
    for (const src of SOURCES) {
      if (!m.getSource(src.id)) m.addSource(src.id, { type: "geojson", data: { type: "FeatureCollection", features: [] } });
    }
    const add = (layer: Parameters<MlMap["addLayer"]>[0]) => {
      if (!m.getLayer(layer.id)) m.addLayer(layer);
    };
    add({ id: "pf-ghost-line", type: "line", source: "pf-ghost", paint: { "line-color": "#111827", "line-opacity": 0.3, "line-width": 5 }, layout: { "line-cap": "round", "line-join": "round" } });
    add({ id: "pf-track-casing", type: "line", source: "pf-track", paint: { "line-color": "#ffffff", "line-width": 5, "line-opacity": 0.9 }, layout: { "line-cap": "round", "line-join": "round" } });
    add({ id: "pf-track-line", type: "line", source: "pf-track", paint: { "line-color": "#0f172a", "line-width": 2.5 }, layout: { "line-cap": "round", "line-join": "round" } });
    add({
      id: "pf-track-arrows",
      type: "symbol",
      source: "pf-track",
      layout: { "symbol-placement": "line", "symbol-spacing": 80, "icon-image": "pf-chevron", "icon-size": 0.9, "icon-allow-overlap": true, "icon-ignore-placement": true },
      paint: { "icon-color": "#0f172a", "icon-halo-color": "#fff", "icon-halo-width": 1 },
    });
    add({
      id: "pf-selection-ring",
      type: "circle",
      source: "pf-selection",
      paint: {
        "circle-radius": 13,
        "circle-color": "rgba(0,0,0,0)",
        "circle-stroke-width": 3,
        "circle-stroke-color": ["match", ["get", "kind"], "anchor", "#a21caf", "#0ea5e9"],
      },
    });
    // A wider transparent circle to grab keyframes with a finger or a quick mouse.
    add({
      id: KEYFRAME_LAYER,
      type: "circle",
      source: "pf-keyframes",
      paint: { "circle-radius": ["interpolate", ["linear"], ["zoom"], 12, 4, 17, 14], "circle-color": "#000", "circle-opacity": 0 },
    });
    add({
      id: "pf-kf-circle",
      type: "circle",
      source: "pf-keyframes",
      paint: {
        "circle-radius": ["interpolate", ["linear"], ["zoom"], 12, ["match", ["get", "s"], "fixed", 2, 3], 17, ["match", ["get", "s"], "fixed", 4, 7]],
        "circle-color": statusColor as never,
        // The dragged keyframe is hidden by feature state (no re-tiling of 10,000 points).
        "circle-opacity": ["case", ["boolean", ["feature-state", "dragging"], false], 0, ["match", ["get", "s"], "deleted", 0.45, 1]],
        "circle-stroke-opacity": ["case", ["boolean", ["feature-state", "dragging"], false], 0, 1],
        "circle-stroke-color": "#ffffff",
        "circle-stroke-width": ["interpolate", ["linear"], ["zoom"], 12, 0.5, 17, 1.5],
      },
    });
    add({
      id: "pf-kf-heading",
      type: "symbol",
      source: "pf-keyframes",
      minzoom: 14,
      filter: ["!=", ["get", "s"], "fixed"],
      layout: {
        "icon-image": "pf-arrow",
        "icon-size": ["interpolate", ["linear"], ["zoom"], 14, 0.5, 18, 1],
        "icon-rotate": ["get", "h"],
        "icon-rotation-alignment": "map",
        "icon-offset": [0, -14],
        "icon-allow-overlap": true,
        "icon-ignore-placement": true,
      },
      paint: {
        "icon-color": statusColor as never,
        "icon-halo-color": "#fff",
        "icon-halo-width": 1,
        "icon-opacity": ["case", ["boolean", ["feature-state", "dragging"], false], 0, 1],
      },
    });
    add({ id: "pf-staging-rubber", type: "line", source: "pf-staging", filter: ["==", ["get", "kind"], "rubber"], paint: { "line-color": "#0ea5e9", "line-width": 2, "line-dasharray": [2, 2] } });
    add({ id: "pf-staging-point", type: "circle", source: "pf-staging", filter: ["==", ["get", "kind"], "point"], paint: { "circle-radius": 8, "circle-color": "#0ea5e9", "circle-stroke-color": "#fff", "circle-stroke-width": 2 } });
    add({ id: "pf-refusal-ring", type: "circle", source: "pf-refusal", paint: { "circle-radius": 14, "circle-color": "rgba(220,38,38,0.15)", "circle-stroke-color": "#dc2626", "circle-stroke-width": 3 } });
    const cmp = (kind: string, extra: unknown[] = []) => (extra.length ? ["all", ["==", ["get", "kind"], kind], extra] : ["==", ["get", "kind"], kind]) as never;
    add({ id: "pf-compare-from", type: "line", source: "pf-compare", filter: cmp("track", ["==", ["get", "which"], "from"]), paint: { "line-color": COMPARE_FROM, "line-width": 3, "line-dasharray": [2, 1.5] } });
    add({ id: "pf-compare-to", type: "line", source: "pf-compare", filter: cmp("track", ["==", ["get", "which"], "to"]), paint: { "line-color": COMPARE_TO, "line-width": 3 } });
    add({ id: "pf-compare-link", type: "line", source: "pf-compare", filter: cmp("link"), paint: { "line-color": COMPARE_TO, "line-width": 1.5 } });
    add({ id: "pf-compare-moved", type: "circle", source: "pf-compare", filter: cmp("moved"), paint: { "circle-radius": 5, "circle-color": COMPARE_TO, "circle-stroke-color": "#fff", "circle-stroke-width": 1.5 } });
    const sug = (kind: string) => ["==", ["get", "kind"], kind] as never;
    add({ id: "pf-sug-path", type: "line", source: "pf-suggestions", filter: sug("path"), paint: { "line-color": SUGGESTION_COLOR, "line-width": 2, "line-opacity": 0.7, "line-dasharray": [3, 2] } });
    add({ id: "pf-sug-link", type: "line", source: "pf-suggestions", filter: sug("link"), paint: { "line-color": SUGGESTION_COLOR, "line-width": 1.5, "line-dasharray": [1, 1.5] } });
    add({ id: "pf-sug-offroad", type: "circle", source: "pf-suggestions", filter: sug("offroad"), paint: { "circle-radius": 11, "circle-color": "rgba(0,0,0,0)", "circle-stroke-color": OFFROAD_COLOR, "circle-stroke-width": 2 } });
    add({
      id: "pf-sug-focus", type: "circle", source: "pf-suggestions", filter: ["all", ["==", ["get", "kind"], "point"], ["==", ["get", "focus"], true]] as never,
      paint: { "circle-radius": 12, "circle-color": "rgba(0,0,0,0)", "circle-stroke-color": SUGGESTION_COLOR, "circle-stroke-width": 3 },
    });
    add({
      id: SUGGESTION_POINT_LAYER, type: "circle", source: "pf-suggestions", filter: sug("point"),
      paint: { "circle-radius": 6, "circle-color": ["case", ["get", "accepted"], SUGGESTION_COLOR, "#ffffff"], "circle-stroke-color": SUGGESTION_COLOR, "circle-stroke-width": 2.5 },
    });
    this.lastDeps.clear();
    this.hidden = null;
  }

  /** Push the sources whose inputs changed since the last call. */
  render(s: EditorState): void {
    for (const src of SOURCES) {
      const deps = src.deps(s);
      const last = this.lastDeps.get(src.id);
      if (last && last.length === deps.length && last.every((d, i) => d === deps[i])) continue;
      const source = this.map.getSource(src.id) as GeoJSONSource | undefined;
      if (!source) continue;
      source.setData(src.build(s));
      this.lastDeps.set(src.id, deps);
    }
    const hide = s.staging ? s.staging.index : null;
    if (hide !== this.hidden && this.map.getSource("pf-keyframes")) {
      // Hide the dragged keyframe itself; the staging point stands in for it.
      if (this.hidden !== null) this.map.setFeatureState({ source: "pf-keyframes", id: this.hidden }, { dragging: false });
      if (hide !== null) this.map.setFeatureState({ source: "pf-keyframes", id: hide }, { dragging: true });
      this.hidden = hide;
    }
    this.setVisible("pf-ghost-line", s.showGhost);
  }

  private setVisible(layer: string, on: boolean): void {
    if (!this.map.getLayer(layer)) return;
    const v = on ? "visible" : "none";
    if (this.map.getLayoutProperty(layer, "visibility") !== v) this.map.setLayoutProperty(layer, "visibility", v);
  }
}
