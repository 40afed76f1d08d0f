/**
 * The one place a MapLibre map is made: the server's style (or a blank one, so pages still
 * work without a basemap), the bundled worker, the default centre and the controls every
 * page shares. The editor, the task pages and the review page all call `createMap`.
 */
import * as maplibregl from "maplibre-gl";
import type { Map as MlMap, StyleSpecification } from "maplibre-gl";
// MapLibre's worker is its own module file; hand its bundled URL to MapLibre (works offline).
import workerUrl from "maplibre-gl/dist/maplibre-gl-worker.mjs?url";
import { api } from "../api/endpoints";

/** Helsinki: where the bundled street basemap and the simulated drives are. */
export const DEFAULT_CENTER: [number, number] = [24.94, 60.17];
export const DEFAULT_ZOOM = 12;

/** A plain style to fall back on when the server has no basemap (the editor still works). */
export const BLANK_STYLE: StyleSpecification = {
  version: 8,
  sources: {},
  layers: [{ id: "background", type: "background", paint: { "background-color": "#eef2f5" } }],
};

/** Fetch the style; the blank one (and the reason) when it cannot be had. */
export async function fetchStyle(): Promise<{ style: StyleSpecification; note: string | null }> {
  try {
    const res = await fetch(api.styleUrl(), { credentials: "same-origin" });
    if (!res.ok) return { style: BLANK_STYLE, note: `No basemap (style.json: ${res.status}).` };
    return { style: (await res.json()) as StyleSpecification, note: null };
  } catch (err) {
    return { style: BLANK_STYLE, note: `No basemap: ${(err as Error).message}` };
  }
}

export interface MapOptions {
  /** A style of the page's own instead of the server's basemap (e.g. a floor in its own frame). */
  style?: StyleSpecification;
  center?: [number, number];
  zoom?: number;
  /** Zoom/rotate buttons (top left). */
  navigation?: boolean;
  /** A metric scale bar (bottom right). */
  scale?: boolean;
  /** Collapsed attribution, for small maps. */
  compactAttribution?: boolean;
  /** Exposed on `window[name]` for the end-to-end tests and the benchmarks. */
  exposeAs?: string;
  /** False once the page has gone: no map is made (the style can take a while). */
  alive?: () => boolean;
}

export interface CreatedMap {
  map: MlMap;
  style: StyleSpecification;
  /** Why there is no basemap, when there is none. */
  note: string | null;
}

export async function createMap(container: HTMLElement, opts: MapOptions = {}): Promise<CreatedMap | null> {
  maplibregl.setWorkerUrl(workerUrl);
  const { style, note } = opts.style ? { style: opts.style, note: null } : await fetchStyle();
  if (opts.alive && !opts.alive()) return null;
  const map = new maplibregl.Map({
    container,
    style,
    center: opts.center ?? DEFAULT_CENTER,
    zoom: opts.zoom ?? DEFAULT_ZOOM,
    attributionControl: false,
    dragRotate: true,
    fadeDuration: 0,
  });
  if (opts.exposeAs) (window as unknown as Record<string, unknown>)[opts.exposeAs] = map;
  if (opts.navigation) map.addControl(new maplibregl.NavigationControl({ visualizePitch: false }), "top-left");
  if (opts.scale) map.addControl(new maplibregl.ScaleControl({ unit: "metric" }), "bottom-right");
  map.addControl(new maplibregl.AttributionControl({ compact: !!opts.compactAttribution }), "bottom-right");
  return { map, style, note };
}

/** Fit `[minLon, minLat, maxLon, maxLat]` boxes (all of them) into the map. */
export function fitBoxes(map: MlMap, boxes: readonly (readonly number[])[], opts: { padding?: number; maxZoom?: number; animate?: boolean } = {}): void {
  if (boxes.length === 0) return;
  const b = [Math.min(...boxes.map((x) => x[0])), Math.min(...boxes.map((x) => x[1])), Math.max(...boxes.map((x) => x[2])), Math.max(...boxes.map((x) => x[3]))];
  if (!b.every(Number.isFinite)) return;
  map.fitBounds([[b[0], b[1]], [b[2], b[3]]], { padding: opts.padding ?? 40, animate: opts.animate ?? false, maxZoom: opts.maxZoom ?? 18 });
}
