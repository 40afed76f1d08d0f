/**
 * Browse: hover shows a grab cursor over keyframes; press on one starts a drag (mouse or
 * touch); click selects; right-click opens its images.
 */
import type { MapLayerMouseEvent, MapLayerTouchEvent } from "maplibre-gl";
import { select } from "../actions/editor";
import { KEYFRAME_LAYER } from "../map/adapter";
import type { Mode, ModeContext } from "./types";

export function modeBrowse(): Mode {
  let off: (() => void)[] = [];
  return {
    name: "browse",
    enter(ctx: ModeContext) {
      const { map, store } = ctx;
      const canvas = map.getCanvasContainer();
      // The keyframe nearest the pointer among those under it (hit circles overlap when zoomed out).
      const hitIndex = (e: { point: { x: number; y: number }; features?: { properties: Record<string, unknown>; geometry: unknown }[] }) => {
        if (!e.features || e.features.length === 0) return null;
        let best: number | null = null;
        let bestD = Infinity;
        for (const f of e.features) {
          const c = (f.geometry as { coordinates: [number, number] }).coordinates;
          const p = map.project(c);
          const d = (p.x - e.point.x) ** 2 + (p.y - e.point.y) ** 2;
          if (d < bestD) {
            bestD = d;
            best = Number(f.properties.i);
          }
        }
        return best;
      };

      const onEnter = () => (canvas.style.cursor = "grab");
      const onLeave = () => (canvas.style.cursor = "");
      const onDown = (e: MapLayerMouseEvent) => {
        if (e.originalEvent.button !== 0) return;
        const i = hitIndex(e);
        if (i === null) return;
        e.preventDefault(); // keep the map from panning
        ctx.switchTo("drag", { index: i, lonlat: [e.lngLat.lng, e.lngLat.lat], touch: false });
      };
      const onTouch = (e: MapLayerTouchEvent) => {
        if (e.points.length !== 1) return;
        const i = hitIndex(e);
        if (i === null) return;
        e.preventDefault();
        ctx.switchTo("drag", { index: i, lonlat: [e.lngLat.lng, e.lngLat.lat], touch: true });
      };
      const onContext = (e: MapLayerMouseEvent) => {
        const i = hitIndex(e);
        if (i === null) return;
        e.preventDefault();
        store.update((s) => select(s, i));
        ctx.openImages(i);
      };
      map.on("mouseenter", KEYFRAME_LAYER, onEnter);
      map.on("mouseleave", KEYFRAME_LAYER, onLeave);
      map.on("mousedown", KEYFRAME_LAYER, onDown);
      map.on("touchstart", KEYFRAME_LAYER, onTouch);
      map.on("contextmenu", KEYFRAME_LAYER, onContext);
      off = [
        () => map.off("mouseenter", KEYFRAME_LAYER, onEnter),
        () => map.off("mouseleave", KEYFRAME_LAYER, onLeave),
        () => map.off("mousedown", KEYFRAME_LAYER, onDown),
        () => map.off("touchstart", KEYFRAME_LAYER, onTouch),
        () => map.off("contextmenu", KEYFRAME_LAYER, onContext),
      ];
    },
    exit() {
      for (const f of off) f();
      off = [];
    },
  };
}
