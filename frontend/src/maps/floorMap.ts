/**
 * The floor plan on a MapLibre map (the one factory, `createMap`): a georeferenced floor lies
 * over the basemap where it is; one without a georeference sits in its own metric frame on a
 * blank style. The walk being replayed is drawn with it: matched and dead-reckoning tracks up
 * to the step shown, and the position at that step. The canvas beside it stays the offline view.
 */
import type { GeoJSONSource, Map as MlMap } from "maplibre-gl";
import { BLANK_STYLE, createMap } from "../map/createMap";
import { h } from "../ui/dom";
import type { FloorPlan, WalkTrack } from "./api";
import { floorCorners, floorLonLat, walkFeatures } from "./floorView";

export class FloorMap {
  readonly el = h("div", { class: "floor-map", "data-testid": "floor-map", role: "region", "aria-label": "Floor plan on the map" });
  private map: MlMap | null = null; // once loaded
  private made: MlMap | null = null;
  private pending: GeoJSON.FeatureCollection | null = null;

  constructor(private readonly alive: () => boolean) {}

  /** Make the map once the floor is known; `imageUrl` when the floor has an image. */
  async show(fp: FloorPlan, imageUrl: string | null): Promise<void> {
    const georef = !!fp.georef && fp.georef.length === 4;
    const made = await createMap(this.el, {
      style: georef ? undefined : BLANK_STYLE,
      center: floorLonLat(fp, fp.width_m / 2, fp.height_m / 2),
      navigation: true,
      scale: true,
      compactAttribution: true,
      exposeAs: "__posefixFloorMap",
      alive: this.alive,
    });
    if (!made) return;
    const map = made.map;
    this.made = map;
    const corners = floorCorners(fp);
    map.on("load", () => {
      if (imageUrl) {
        map.addSource("floor-image", { type: "image", url: imageUrl, coordinates: corners });
        map.addLayer({ id: "floor-image", type: "raster", source: "floor-image", paint: { "raster-opacity": 0.9, "raster-fade-duration": 0 } });
      }
      map.addSource("floor-outline", { type: "geojson", data: { type: "Feature", properties: {}, geometry: { type: "Polygon", coordinates: [[...corners, corners[0]]] } } });
      map.addLayer({ id: "floor-outline", type: "line", source: "floor-outline", paint: { "line-color": "#94a3b8", "line-width": 1.5 } });
      map.addSource("floor-walk", { type: "geojson", data: this.pending ?? walkFeatures(fp, null, 0) });
      map.addLayer({ id: "floor-dr", type: "line", source: "floor-walk", filter: ["==", ["get", "kind"], "dr"], paint: { "line-color": "#64748b", "line-width": 2, "line-dasharray": [3, 2] } });
      map.addLayer({ id: "floor-matched", type: "line", source: "floor-walk", filter: ["==", ["get", "kind"], "matched"], paint: { "line-color": "#1d4ed8", "line-width": 3 } });
      map.addLayer({ id: "floor-position", type: "circle", source: "floor-walk", filter: ["==", ["get", "kind"], "position"], paint: { "circle-color": "#1d4ed8", "circle-radius": 5, "circle-stroke-color": "#fff", "circle-stroke-width": 1.5 } });
      const lons = corners.map((c) => c[0]);
      const lats = corners.map((c) => c[1]);
      map.fitBounds([[Math.min(...lons), Math.min(...lats)], [Math.max(...lons), Math.max(...lats)]], { padding: 20, animate: false, maxZoom: 22 });
      this.map = map;
      this.el.dataset.ready = "true";
    });
  }

  /** Draw the walk up to step `n` (before the map is ready: kept for when it is). */
  render(fp: FloorPlan, track: WalkTrack | null, n: number): void {
    const data = walkFeatures(fp, track, n);
    this.pending = data;
    (this.map?.getSource("floor-walk") as GeoJSONSource | undefined)?.setData(data);
    this.el.dataset.step = track ? String(Math.min(n, track.steps.length - 1)) : "";
  }

  remove(): void {
    this.made?.remove();
    this.made = this.map = null;
  }
}
