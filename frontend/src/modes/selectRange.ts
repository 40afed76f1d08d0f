/**
 * Select range: click a first and a last keyframe; the range between them (inclusive) is
 * marked for deletion as one step. Escape leaves without a change.
 */
import type { MapLayerMouseEvent } from "maplibre-gl";
import { KEYFRAME_LAYER } from "../map/adapter";
import type { Mode, ModeContext } from "./types";

export function modeSelectRange(): Mode {
  let off: (() => void)[] = [];
  return {
    name: "select-range",
    enter(ctx: ModeContext) {
      const { map, store } = ctx;
      map.getCanvasContainer().style.cursor = "crosshair";
      const onClick = (e: MapLayerMouseEvent) => {
        const f = e.features?.[0];
        if (!f) return;
        const i = Number(f.properties.i);
        const anchor = store.get().rangeAnchor;
        if (anchor === null) {
          store.update((s) => ({ ...s, rangeAnchor: i, selected: i }));
          return;
        }
        ctx.switchTo("browse");
        ctx.commitRange(anchor, i);
      };
      const onKey = (e: KeyboardEvent) => {
        if (e.key === "Escape") ctx.switchTo("browse");
      };
      map.on("click", KEYFRAME_LAYER, onClick);
      window.addEventListener("keydown", onKey);
      off = [
        () => map.off("click", KEYFRAME_LAYER, onClick),
        () => window.removeEventListener("keydown", onKey),
        () => (map.getCanvasContainer().style.cursor = ""),
      ];
    },
    exit() {
      for (const f of off) f();
      off = [];
    },
  };
}
