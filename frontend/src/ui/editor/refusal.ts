/** A refusal shown where the operator acted: a popup on the map and a screen-reader alert. */
import * as maplibregl from "maplibre-gl";
import type { Map as MlMap, Popup } from "maplibre-gl";
import type { EditorState } from "../../state/editor";
import { h } from "../dom";

export function refusalTitle(reason: string): string {
  switch (reason) {
    case "too_far": return "Too far from the reported position";
    case "locked": return "Keyframe is locked";
    case "not_adjustable": return "Keyframe is not adjustable";
    case "order_reversed": return "Poses would run backwards";
    case "deleted": return "Keyframe is marked for deletion";
    case "out_of_range": return "No such keyframe";
    case "duplicate": return "Moved twice";
    default: return "Edit refused";
  }
}

export class RefusalView {
  readonly live = h("div", { class: "sr-only", role: "alert", "data-testid": "refusal-live" });
  private popup: Popup | null = null;

  constructor(private readonly onClose: () => void) {}

  show(s: EditorState, map: MlMap | null): void {
    this.remove();
    if (!s.refusal) {
      this.live.textContent = "";
      return;
    }
    const r = s.refusal;
    this.live.textContent = `Refused: ${r.message}`;
    if (!map) return;
    const body = h("div", { class: "refusal", "data-testid": "refusal", "data-reason": r.reason },
      h("strong", {}, refusalTitle(r.reason)), h("p", {}, r.message));
    this.popup = new maplibregl.Popup({ closeButton: true, closeOnClick: true, className: "refusal-popup", maxWidth: "280px" })
      .setLngLat(r.at as [number, number])
      .setDOMContent(body)
      .addTo(map);
    this.popup.on("close", this.onClose);
  }

  remove(): void {
    this.popup?.remove();
    this.popup = null;
  }
}
