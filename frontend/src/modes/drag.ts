/**
 * Drag: the keyframe follows the pointer as a staged position (no edit yet); on release the
 * move is committed as one step (rules checked, then the server preview); Escape cancels.
 * Map panning is off while dragging.
 */
import type { MapMouseEvent, MapTouchEvent } from "maplibre-gl";
import { clearStaging, select, stageDrag } from "../actions/editor";
import type { LonLat } from "../state/types";
import type { DragStart, Mode, ModeContext } from "./types";

/** Pointer travel (px) below which a press counts as a click (select), not a drag. */
const CLICK_TOLERANCE_PX = 3;

export function modeDrag(): Mode {
  let off: (() => void)[] = [];
  return {
    name: "drag",
    enter(ctx: ModeContext, start?: DragStart) {
      if (!start) throw new Error("drag mode needs a start keyframe");
      const { map, store } = ctx;
      const startPx = map.project(start.lonlat as [number, number]);
      let moved = false;
      let last: LonLat = start.lonlat;
      map.dragPan.disable();
      map.getCanvasContainer().style.cursor = "grabbing";

      // Pointer events can outnumber frames: stage at most once per animation frame.
      let frame = 0;
      const flush = () => {
        frame = 0;
        store.update((s) => stageDrag(s, start.index, last));
      };
      const onMove = (e: MapMouseEvent | MapTouchEvent) => {
        if (!moved && startPx.dist(e.point) < CLICK_TOLERANCE_PX) return;
        moved = true;
        last = [e.lngLat.lng, e.lngLat.lat];
        if (!frame) frame = requestAnimationFrame(flush);
      };
      const onUp = (e?: MapMouseEvent | MapTouchEvent) => {
        if (e && "lngLat" in e && e.type !== "touchend") last = [e.lngLat.lng, e.lngLat.lat];
        ctx.switchTo("browse");
        if (moved) ctx.commitMove(start.index, last);
        else store.update((s) => clearStaging(select(s, start.index)));
      };
      const onKey = (e: KeyboardEvent) => {
        if (e.key === "Escape") {
          moved = false;
          store.update(clearStaging);
          ctx.switchTo("browse");
        }
      };
      const onTouchMove = (e: MapTouchEvent) => {
        e.preventDefault();
        onMove(e);
      };
      const onMouseUp = (e: MapMouseEvent) => onUp(e);
      const onTouchEnd = () => onUp();
      map.on("mousemove", onMove);
      map.on("mouseup", onMouseUp);
      map.on("touchmove", onTouchMove);
      map.on("touchend", onTouchEnd);
      map.on("touchcancel", onTouchEnd);
      window.addEventListener("keydown", onKey);
      off = [
        () => cancelAnimationFrame(frame),
        () => map.off("mousemove", onMove),
        () => map.off("mouseup", onMouseUp),
        () => map.off("touchmove", onTouchMove),
        () => map.off("touchend", onTouchEnd),
        () => map.off("touchcancel", onTouchEnd),
        () => window.removeEventListener("keydown", onKey),
        () => map.dragPan.enable(),
        () => (map.getCanvasContainer().style.cursor = ""),
      ];
    },
    exit() {
      for (const f of off) f();
      off = [];
    },
  };
}
