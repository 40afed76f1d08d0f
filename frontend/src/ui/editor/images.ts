/** The images panel: a keyframe's images (several cameras: step through them) with time and position. */
import { type ImagePublic, api } from "../../api/endpoints";
import type { Keyframe, LonLat } from "../../state/types";
import { h } from "../dom";
import { formatRunTime } from "./panels";

export class ImagesPanel {
  readonly el: HTMLElement;
  private kf: Keyframe | null = null;
  private pos: LonLat = [0, 0];
  private at = 0;
  isOpen = false;

  /** `enlarge(keyframe, camera)` opens the larger view on that image. */
  constructor(private readonly enlarge: (keyframe: number, camera: number) => void) {
    this.el = h("section", { class: "images-panel", "aria-label": "Images", "data-testid": "images-panel", hidden: true });
  }

  /** Start time of the run, to show image times as seconds into it. */
  t0_s = 0;
  /** Per-image metadata (file name, EXIF position/time) when the server gave it. */
  meta = new Map<string, ImagePublic>();

  open(kf: Keyframe, pos: LonLat): void {
    if (this.kf?.index !== kf.index) this.at = 0;
    this.kf = kf;
    this.pos = pos;
    this.isOpen = true;
    this.render();
  }

  close(): void {
    this.isOpen = false;
    this.el.hidden = true;
  }

  private step(d: number): void {
    if (!this.kf || this.kf.images.length === 0) return;
    const n = this.kf.images.length;
    this.at = (this.at + d + n) % n;
    this.render();
  }

  private render(): void {
    const kf = this.kf;
    if (!kf) return;
    this.el.hidden = false;
    const n = kf.images.length;
    const head = h("div", { class: "row spread" },
      h("h2", {}, `Images of keyframe #${kf.index}`),
      h("button", { type: "button", "aria-label": "Close images", onclick: () => this.close() }, "×"));
    const meta = h("p", { class: "muted", "data-testid": "image-meta" }, `${formatRunTime(kf.t_s, this.t0_s)} · ${this.pos[1].toFixed(6)}, ${this.pos[0].toFixed(6)}`);
    if (n === 0) {
      this.el.replaceChildren(head, meta, h("p", {}, "No images for this keyframe."));
      return;
    }
    const id = kf.images[this.at];
    const m = this.meta.get(id);
    const exif = m && m.exif_lat !== null && m.exif_lon !== null ? ` · EXIF ${m.exif_lat.toFixed(6)}, ${m.exif_lon.toFixed(6)}${m.exif_time ? ` at ${m.exif_time}` : ""}` : "";
    const img = h("img", { src: api.imageUrl(id), alt: `Camera image ${this.at + 1} of ${n} at keyframe ${kf.index}`, "data-testid": "image", loading: "eager" });
    img.addEventListener("error", () => img.replaceWith(h("p", { class: "error" }, `Image ${id} could not be loaded.`)));
    // Scrolling over the image steps through the cameras.
    img.addEventListener("wheel", (e) => {
      if (n < 2) return;
      e.preventDefault();
      this.step(e.deltaY > 0 ? 1 : -1);
    }, { passive: false });
    const big = h("button", { type: "button", class: "enlarge", title: "Larger view: step through the run's images", onclick: () => this.enlarge(kf.index, this.at) }, img);
    this.el.replaceChildren(
      head,
      big,
      h("div", { class: "row" },
        h("button", { type: "button", onclick: () => this.step(-1), disabled: n < 2, "aria-label": "Previous camera image" }, "‹"),
        h("span", { "data-testid": "image-count" }, `Camera image ${this.at + 1} of ${n}`),
        h("button", { type: "button", onclick: () => this.step(+1), disabled: n < 2, "aria-label": "Next camera image" }, "›"),
        h("button", { type: "button", "data-testid": "images-enlarge", onclick: () => this.enlarge(kf.index, this.at) }, "Larger view")),
      m ? h("p", { class: "muted" }, m.filename) : "",
      meta,
      exif ? h("p", { class: "muted" }, exif.slice(3)) : "",
    );
  }
}
