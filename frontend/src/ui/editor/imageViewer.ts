/**
 * The larger image view: docked over the map's right part (the keyframe stays in view on the
 * left), or full screen. It steps through the run's images (buttons, keys, a filmstrip and a
 * scrubber) and reports each image's keyframe so the editor selects it and the map follows.
 */
import { type RunImage, filmstripWindow, imageAt, stepImage, stepKeyframe } from "../../actions/images";
import { type ImagePublic, api } from "../../api/endpoints";
import { h } from "../dom";

const FILMSTRIP_FRAMES = 11;

export class ImageViewer {
  readonly el: HTMLDialogElement;
  private readonly body: HTMLElement;
  /** One image element for the whole walk, so keyboard focus stays on it while stepping. */
  private readonly img = h("img", { alt: "", "data-testid": "viewer-image", tabindex: "0" });
  private readonly stage = h("div", { class: "viewer-stage" }, this.img);
  private readonly failed = h("p", { class: "error", hidden: true });
  private readonly caption = h("p", { class: "viewer-caption", "data-testid": "viewer-caption", "aria-live": "polite" });
  private readonly strip = h("div", { class: "filmstrip", role: "group", "aria-label": "Filmstrip of the run's images", "data-testid": "filmstrip" });
  private readonly scrub = h("input", { type: "range", min: "0", max: "0", value: "0", "aria-label": "Image along the run", "data-testid": "viewer-scrub" });
  private readonly fullBtn = h("button", { type: "button", "data-testid": "viewer-fullscreen", title: "Full screen (F)" }, "Full screen");
  private seq: RunImage[] = [];
  private at = -1;
  meta = new Map<string, ImagePublic>();

  /** `follow(keyframe)`: the editor selects the image's keyframe (the map follows). */
  constructor(private readonly follow: (keyframe: number) => void, private readonly onClose: () => void) {
    const prev = h("button", { type: "button", "aria-label": "Previous image (←)", "data-testid": "viewer-prev", onclick: () => this.go(stepImage(this.seq, this.at, -1)) }, "‹ Previous");
    const next = h("button", { type: "button", "aria-label": "Next image (→)", "data-testid": "viewer-next", onclick: () => this.go(stepImage(this.seq, this.at, 1)) }, "Next ›");
    const close = h("button", { type: "button", "aria-label": "Close the larger view (Esc)", "data-testid": "viewer-close", onclick: () => this.close() }, "×");
    this.fullBtn.addEventListener("click", () => void this.toggleFullscreen());
    this.scrub.addEventListener("input", () => this.go(Number(this.scrub.value)));
    this.body = h("div", { class: "viewer-body" },
        h("div", { class: "row spread" }, this.caption, h("div", { class: "row" }, this.fullBtn, close)),
        this.stage,
        h("div", { class: "row viewer-nav" }, prev, this.scrub, next),
        this.strip,
        h("p", { class: "muted keys-hint" }, h("kbd", {}, "←"), " / ", h("kbd", {}, "→"), " image · ", h("kbd", {}, "PgUp"), " / ", h("kbd", {}, "PgDn"), " keyframe · ",
          h("kbd", {}, "F"), " full screen · ", h("kbd", {}, "Esc"), " close"));
    // A dialog cannot go full screen itself; its body can.
    this.el = h("dialog", { class: "image-viewer", "aria-label": "Images of the run", "data-testid": "image-viewer" }, this.body);
    this.el.addEventListener("keydown", (e) => this.onKey(e));
    this.stage.append(this.failed);
    this.img.addEventListener("error", () => {
      this.failed.hidden = false;
      this.failed.textContent = `Image ${this.seq[this.at]?.id ?? ""} could not be loaded.`;
    });
    this.img.addEventListener("load", () => (this.failed.hidden = true));
    document.addEventListener("fullscreenchange", this.onFullscreen);
  }

  get isOpen(): boolean {
    return this.el.open;
  }

  /** Open on keyframe `keyframe`'s camera `camera` (the sequence is the run's images in order). */
  open(seq: RunImage[], keyframe: number, camera = 0): void {
    this.seq = seq;
    this.scrub.max = String(Math.max(0, seq.length - 1));
    if (!this.el.open) this.el.show();
    this.go(imageAt(seq, keyframe, camera), false);
    this.img.focus();
  }

  close(): void {
    if (document.fullscreenElement) void document.exitFullscreen().catch(() => undefined);
    if (this.el.open) this.el.close();
    this.onClose();
  }

  dispose(): void {
    document.removeEventListener("fullscreenchange", this.onFullscreen);
  }

  private onFullscreen = () => {
    const on = document.fullscreenElement === this.body;
    this.el.classList.toggle("fullscreen", on);
    this.fullBtn.textContent = on ? "Exit full screen" : "Full screen";
  };

  private async toggleFullscreen(): Promise<void> {
    try {
      if (document.fullscreenElement) await document.exitFullscreen();
      else await this.body.requestFullscreen();
    } catch (err) {
      this.caption.textContent = `Full screen is not available here: ${(err as Error).message}`;
    }
  }

  private onKey(e: KeyboardEvent): void {
    if ((e.target as HTMLElement).tagName === "INPUT") return; // the scrubber has its own arrows
    let to: number | null = null;
    if (e.key === "ArrowRight" || e.key === ".") to = stepImage(this.seq, this.at, 1);
    else if (e.key === "ArrowLeft" || e.key === ",") to = stepImage(this.seq, this.at, -1);
    else if (e.key === "PageDown") to = stepKeyframe(this.seq, this.at, 1);
    else if (e.key === "PageUp") to = stepKeyframe(this.seq, this.at, -1);
    else if (e.key === "Home") to = 0;
    else if (e.key === "End") to = this.seq.length - 1;
    else if (e.key === "f" || e.key === "F") void this.toggleFullscreen();
    else if (e.key === "Escape" && document.fullscreenElement) void document.exitFullscreen().catch(() => undefined);
    else if (e.key === "Escape") this.close();
    else return;
    e.preventDefault();
    e.stopPropagation();
    if (to !== null) this.go(to);
  }

  private go(at: number, follow = true): void {
    if (at < 0 || at >= this.seq.length) {
      this.caption.textContent = "This run has no images.";
      return;
    }
    const keyframeChanged = this.seq[this.at]?.keyframe !== this.seq[at].keyframe;
    this.at = at;
    const im = this.seq[at];
    const m = this.meta.get(im.id);
    const src = api.imageUrl(im.id);
    if (this.img.getAttribute("src") !== src) this.img.src = src;
    this.img.alt = `Camera ${im.camera + 1} of ${im.cameras} at keyframe ${im.keyframe}`;
    this.el.dataset.keyframe = String(im.keyframe);
    this.el.dataset.at = String(at);
    this.caption.textContent = `Keyframe #${im.keyframe} · camera ${im.camera + 1} of ${im.cameras} · image ${at + 1} of ${this.seq.length}${m ? ` · ${m.filename}` : ""}`;
    this.scrub.value = String(at);
    this.renderStrip();
    if (follow && keyframeChanged) this.follow(im.keyframe);
  }

  private renderStrip(): void {
    const [a, b] = filmstripWindow(this.seq.length, this.at, FILMSTRIP_FRAMES);
    const frames: HTMLElement[] = [];
    for (let i = a; i < b; i++) {
      const im = this.seq[i];
      const btn = h("button", { type: "button", class: "frame", "aria-label": `Keyframe ${im.keyframe}, camera ${im.camera + 1}`, "aria-current": i === this.at ? "true" : undefined, "data-testid": `frame-${i}` },
        h("img", { src: api.thumbnailUrl(im.id), alt: "", loading: "lazy" }),
        h("span", {}, `#${im.keyframe}`));
      btn.addEventListener("click", () => this.go(i));
      frames.push(btn);
    }
    this.strip.replaceChildren(...frames);
  }
}
