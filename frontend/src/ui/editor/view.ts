/**
 * The correction view: wires the store, the controller, the map adapter, the modes and the
 * DOM panels together. State flows one way: input -> modes/controller -> store -> adapter/panels.
 */
import * as maplibregl from "maplibre-gl";
// MapLibre's worker is its own module file; hand its bundled URL to MapLibre (works offline).
import workerUrl from "maplibre-gl/dist/maplibre-gl-worker.mjs?url";
import type { Map as MlMap, Popup } from "maplibre-gl";
import { dismissRefusal, select, selectNextAdjustable, selectStep, toggleGhost } from "../../actions/editor";
import { actionAcceptAsIs, actionMarkDeleted, actionReset, actionRestore, actionUnmove } from "../../actions/edits";
import { api } from "../../api/endpoints";
import { MapAdapter } from "../../map/adapter";
import { bounds } from "../../map/features";
import { ModeManager } from "../../modes/manager";
import { type EditorState, correctionMagnitudes, currentEdits, displayPositions, editCount, keyframeStatuses } from "../../state/editor";
import type { AppContext } from "../app";
import { clear, h } from "../dom";
import { basemapOptions, basemapSwitcher, fetchStyle, initialBasemap, showBasemap } from "./basemap";
import { CorrectionChart } from "./chart";
import { EditorController } from "./controller";
import { ImagesPanel } from "./images";
import { driftInfo, legend, selectionInfo, statusBar, toolbarState } from "./panels";
import { SuggestionsPanel } from "../../maps/suggestPanel";

export function renderEditor(main: HTMLElement, _app: AppContext, runId: string, onController?: (ctl: EditorController) => void): () => void {
  const ctl = new EditorController(runId);
  onController?.(ctl);
  const store = ctl.store;
  const cleanups: (() => void)[] = [() => ctl.dispose()];

  // ---- layout
  const btn = (label: string, onclick: () => void, attrs: Record<string, unknown> = {}) =>
    h("button", { type: "button", onclick, ...attrs }, label);
  const title = h("h1", { class: "run-title" }, "Loading run…");
  const undoBtn = btn("↶ Undo", () => ctl.undo(), { "data-testid": "undo" });
  const redoBtn = btn("↷ Redo", () => ctl.redo(), { "data-testid": "redo" });
  const deleteBtn = btn("Delete", () => toggleDeleteSelected(), { "data-testid": "delete", title: "Mark the selected keyframe for deletion (Delete)" });
  const rangeBtn = btn("Delete range…", () => modes?.switchTo(store.get().mode === "select-range" ? "browse" : "select-range"), { "data-testid": "delete-range", title: "Click the first and last keyframe of the range (R)" });
  const acceptBtn = btn("Accept as is", () => ctl.perform(actionAcceptAsIs()), { "data-testid": "accept", title: "The run needs no correction" });
  const resetBtn = btn("Reset", () => ctl.perform(actionReset()), { "data-testid": "reset", title: "Drop all unsaved edits (undoable)" });
  const ghostBtn = btn("Ghost", () => store.update(toggleGhost), { "data-testid": "ghost", "aria-pressed": "true", title: "Show the loaded revision under the corrected track (G)" });
  const imagesBtn = btn("Images", () => openImages(store.get().selected), { "data-testid": "images-button", title: "Images of the selected keyframe (I)" });
  const fitBtn = btn("Fit", () => fit(), { title: "Zoom to the whole run (F)" });
  const comment = h("input", { id: "submit-comment", placeholder: "Comment (optional)", "aria-label": "Comment for this submission" });
  const submitBtn = btn("Submit", () => void ctl.submit(comment.value), { class: "primary", "data-testid": "submit" });
  const suggest = new SuggestionsPanel(ctl, (t) => notices.replaceChildren(h("p", {}, t)));
  cleanups.push(() => suggest.dispose());
  const toolbar = h("div", { class: "toolbar", role: "toolbar", "aria-label": "Editing tools" },
    title, undoBtn, redoBtn, h("span", { class: "sep" }), deleteBtn, rangeBtn, acceptBtn, resetBtn, h("span", { class: "sep" }), ghostBtn, imagesBtn, fitBtn,
    h("span", { class: "sep" }), ...suggest.elements,
    h("span", { class: "grow" }), comment, submitBtn);

  const mapEl = h("div", { class: "map", id: "map", "aria-label": "Map of the run; drag keyframes to correct them", role: "application", tabindex: "0" });
  const legendBox = h("div", { class: "legend-box" });
  const basemapBox = h("div", { class: "basemap-box" });
  const mapNote = h("div", { class: "map-note", role: "status" });
  const mapWrap = h("div", { class: "map-wrap" }, mapEl, legendBox, basemapBox, mapNote);

  const selBox = h("div");
  const images = new ImagesPanel();
  const driftBox = h("div");
  const notices = h("div", { class: "notices", role: "status", "aria-live": "polite", "data-testid": "notices" });
  const errorBox = h("div", { class: "error-box", role: "alert", "data-testid": "error", hidden: true });
  const newerBox = h("div", { class: "newer-box", role: "status", "data-testid": "newer", hidden: true });
  const side = h("aside", { class: "side", "aria-label": "Keyframe details" },
    h("h2", {}, "Selected keyframe"), selBox,
    images.el,
    h("h2", {}, "Drift"), driftBox,
    h("h2", {}, "Keys"),
    h("ul", { class: "keys" },
      h("li", {}, h("kbd", {}, "."), " / ", h("kbd", {}, ","), " or ", h("kbd", {}, "→"), " / ", h("kbd", {}, "←"), " next / previous keyframe"),
      h("li", {}, h("kbd", {}, "A"), " next adjustable keyframe"),
      h("li", {}, h("kbd", {}, "Ctrl+Z"), " undo, ", h("kbd", {}, "Ctrl+Shift+Z"), " redo"),
      h("li", {}, h("kbd", {}, "Del"), " delete / restore, ", h("kbd", {}, "R"), " delete a range"),
      h("li", {}, h("kbd", {}, "I"), " images, ", h("kbd", {}, "G"), " ghost, ", h("kbd", {}, "F"), " fit, ", h("kbd", {}, "Esc"), " cancel"),
    ),
    notices,
  );
  const chart = new CorrectionChart((i) => {
    store.update((s) => select(s, i));
    panTo(i);
  });
  const statusEl = h("div", { class: "statusbar", role: "status", "data-testid": "statusbar" });
  const submitMsg = h("span", { class: "submit-msg", "data-testid": "submit-msg" });
  const bottom = h("div", { class: "bottom" }, h("div", { class: "chart-wrap" }, h("span", { class: "chart-title" }, "Correction (m) along the run"), chart.canvas), h("div", { class: "status-row" }, statusEl, submitMsg));
  const conflict = h("div", { class: "conflict", role: "alertdialog", "aria-modal": "true", "aria-labelledby": "conflict-h", "data-testid": "conflict", hidden: true });
  const refusalLive = h("div", { class: "sr-only", role: "alert", "data-testid": "refusal-live" });
  const root = h("div", { class: "editor" }, toolbar, errorBox, newerBox, h("div", { class: "editor-body" }, mapWrap, side), bottom, conflict, refusalLive);
  main.append(root);
  ctl.onNotice = (t) => notices.replaceChildren(h("p", {}, t));

  // ---- map
  let map: MlMap | null = null;
  let adapter: MapAdapter | null = null;
  let modes: ModeManager | null = null;
  let popup: Popup | null = null;
  let fitted = false;
  let closed = false;

  function fit(animate = true) {
    const b = bounds(store.get());
    if (map && b) map.fitBounds([[b[0], b[1]], [b[2], b[3]]], { padding: 60, animate, maxZoom: 18 });
  }
  function panTo(i: number) {
    const s = store.get();
    if (!map || !s.doc) return;
    const p = displayPositions(s)[i];
    const px = map.project(p as [number, number]);
    const c = map.getContainer();
    if (px.x < 40 || px.y < 40 || px.x > c.clientWidth - 40 || px.y > c.clientHeight - 40) map.easeTo({ center: p as [number, number], duration: 250 });
  }
  function openImages(i: number | null) {
    const s = store.get();
    if (i === null || !s.doc) {
      notices.replaceChildren(h("p", {}, "Select a keyframe first to see its images."));
      return;
    }
    images.t0_s = s.doc.keyframes[0]?.t_s ?? 0;
    images.open(s.doc.keyframes[i], currentEdits(s).moves.get(i) ?? s.doc.keyframes[i].lonlat);
  }
  function toggleDeleteSelected() {
    const s = store.get();
    if (s.selected === null || !s.doc) return;
    ctl.perform(currentEdits(s).deleted.has(s.selected) ? actionRestore(s.selected) : actionMarkDeleted(s.selected));
  }

  (async () => {
    maplibregl.setWorkerUrl(workerUrl);
    const { style, note } = await fetchStyle();
    if (closed) return; // left the page while the style was loading
    if (note) mapNote.textContent = note;
    const m = new maplibregl.Map({ container: mapEl, style, center: [24.94, 60.17], zoom: 12, attributionControl: false, dragRotate: true, fadeDuration: 0 });
    map = m;
    // Exposed for the end-to-end tests and the drag benchmark (they project keyframes to pixels).
    (window as unknown as { __posefixMap?: MlMap }).__posefixMap = m;
    m.addControl(new maplibregl.NavigationControl({ visualizePitch: false }), "top-left");
    m.addControl(new maplibregl.ScaleControl({ unit: "metric" }), "bottom-right");
    m.addControl(new maplibregl.AttributionControl({ compact: false }), "bottom-right");
    const opts = basemapOptions(style);
    let current = initialBasemap(style, opts);
    basemapBox.replaceChildren(basemapSwitcher(opts, current, (src) => {
      current = src;
      if (map) showBasemap(map, opts, src);
    }));
    m.on("error", (e) => {
      const msg = (e as unknown as { error?: { message?: string } }).error?.message ?? "";
      if (msg) mapNote.textContent = `Map: ${msg}`;
    });
    m.on("load", () => {
      if (!map) return;
      if (current) showBasemap(map, opts, current);
      adapter = new MapAdapter(map);
      adapter.install();
      suggest.attach(map);
      modes = new ModeManager({
        map,
        store,
        commitMove: (i, p) => ctl.commitMove(i, p),
        commitRange: (a, b) => ctl.commitRange(a, b),
        openImages: (i) => openImages(i),
      });
      mapEl.dataset.ready = "true";
      render(store.get(), null);
    });
  })();
  cleanups.push(() => {
    closed = true;
    modes?.destroy();
    popup?.remove();
    map?.remove();
  });

  // ---- rendering
  let chartDeps: unknown[] = [];
  function render(s: EditorState, prev: EditorState | null) {
    if (s.doc) title.textContent = `${s.doc.name} · rev ${s.doc.revision}`;
    if (adapter) adapter.render(s);
    if (map && s.doc && !fitted && mapEl.dataset.ready === "true") {
      fitted = true;
      fit(false);
    }
    const tb = toolbarState(s);
    undoBtn.disabled = !tb.undo.enabled;
    undoBtn.title = tb.undo.title;
    undoBtn.setAttribute("aria-label", tb.undo.title);
    redoBtn.disabled = !tb.redo.enabled;
    redoBtn.title = tb.redo.title;
    redoBtn.setAttribute("aria-label", tb.redo.title);
    submitBtn.disabled = !tb.submitEnabled;
    deleteBtn.disabled = !tb.hasSelection;
    imagesBtn.disabled = !tb.hasSelection;
    ghostBtn.setAttribute("aria-pressed", String(s.showGhost));
    rangeBtn.setAttribute("aria-pressed", String(s.mode === "select-range"));
    rangeBtn.textContent = s.mode === "select-range" ? (s.rangeAnchor === null ? "Click first keyframe…" : "Click last keyframe…") : "Delete range…";
    statusEl.textContent = statusBar(s);
    root.dataset.revision = String(s.doc?.revision ?? "");
    root.dataset.unsaved = String(editCount(currentEdits(s)));
    root.dataset.previewCurrent = String(!!s.preview && s.preview.forEdits === currentEdits(s));

    const sub = s.submit;
    submitMsg.textContent = sub.kind === "error" ? sub.message : sub.kind === "done" ? `Saved as revision ${sub.revision}.` : "";
    submitMsg.className = `submit-msg ${sub.kind === "error" ? "error" : ""}`;
    errorBox.hidden = !s.error;
    errorBox.textContent = s.error ?? "";
    if (!prev || prev.newer !== s.newer) {
      newerBox.hidden = s.newer === null;
      newerBox.replaceChildren(
        ...(s.newer === null
          ? []
          : [
              `Revision ${s.newer} was saved by someone else while you edit revision ${s.doc?.revision}; submitting now would conflict. `,
              btn("Reload and re-apply my edits", () => void ctl.reloadAndReapply(), { "data-testid": "newer-reapply" }),
            ]),
      );
    }

    const heavy = !prev || prev.doc !== s.doc || currentEdits(prev) !== currentEdits(s) || prev.preview !== s.preview || prev.showGhost !== s.showGhost;
    if (heavy) {
      legendBox.replaceChildren(legend(s));
      driftBox.replaceChildren(driftInfo(s));
    }
    if (heavy || prev?.selected !== s.selected) selBox.replaceChildren(selectionInfo(s));
    const cd = [s.doc, currentEdits(s), s.preview, s.selected];
    if (cd.some((d, i) => d !== chartDeps[i])) {
      chartDeps = cd;
      const st = keyframeStatuses(s);
      chart.set({ now: correctionMagnitudes(s), before: s.doc ? s.doc.keyframes.map((k) => k.correction_m) : [], selected: s.selected, deleted: st.map((x) => x === "deleted") });
    }
    if (prev?.selected !== s.selected && images.isOpen && s.selected !== null && s.doc) openImages(s.selected);
    if (!prev || prev.refusal !== s.refusal) showRefusal(s);
    if (!prev || prev.conflict !== s.conflict) showConflict(s);
  }

  function showRefusal(s: EditorState) {
    popup?.remove();
    popup = null;
    if (!s.refusal) {
      refusalLive.textContent = "";
      return;
    }
    const r = s.refusal;
    refusalLive.textContent = `Refused: ${r.message}`;
    if (!map) return;
    const body = h("div", { class: "refusal", "data-testid": "refusal", "data-reason": r.reason },
      h("strong", {}, refusalTitle(r.reason)), h("p", {}, r.message));
    popup = new maplibregl.Popup({ closeButton: true, closeOnClick: true, className: "refusal-popup", maxWidth: "280px" })
      .setLngLat(r.at as [number, number])
      .setDOMContent(body)
      .addTo(map);
    popup.on("close", () => store.update(dismissRefusal));
  }

  function showConflict(s: EditorState) {
    conflict.hidden = !s.conflict;
    clear(conflict);
    if (!s.conflict) return;
    const n = editCount(currentEdits(s));
    const reapply = btn(`Reload and re-apply my ${n} edit${n === 1 ? "" : "s"}`, () => void ctl.reloadAndReapply(), { class: "primary", "data-testid": "conflict-reapply" });
    conflict.append(h("div", { class: "card" },
      h("h2", { id: "conflict-h" }, "This run has changed since you opened it"),
      h("p", {}, `Someone saved revision ${s.conflict.currentRevision ?? "(newer)"} while you were editing revision ${s.conflict.baseRevision}. Your ${n} unsaved edits are kept in this browser.`),
      h("p", {}, "Reload the run and re-apply your edits on top of the new revision (edits that no longer pass the rules are listed), or discard them."),
      h("div", { class: "row" }, reapply, btn("Discard my edits and reload", () => void ctl.reloadDiscarding(), { "data-testid": "conflict-discard" })),
    ));
    reapply.focus();
  }

  cleanups.push(store.subscribe((next, prev) => render(next, prev)));

  // ---- keyboard
  const onKey = (e: KeyboardEvent) => {
    const t = e.target as HTMLElement | null;
    if (t && (t.tagName === "INPUT" || t.tagName === "TEXTAREA" || t.tagName === "SELECT" || t.isContentEditable)) return;
    const s = store.get();
    if (s.conflict || s.mode === "drag") return;
    const mod = e.ctrlKey || e.metaKey;
    const key = e.key;
    let handled = true;
    if (mod && (key === "z" || key === "Z")) e.shiftKey ? ctl.redo() : ctl.undo();
    else if (mod && (key === "y" || key === "Y")) ctl.redo();
    else if (mod) handled = false;
    else if (key === "." || key === "ArrowRight" || key === "n") store.update((x) => selectStep(x, +1));
    else if (key === "," || key === "ArrowLeft" || key === "p") store.update((x) => selectStep(x, -1));
    else if (key === "a" || key === "A") store.update(selectNextAdjustable);
    else if (key === "Delete" || key === "Backspace") toggleDeleteSelected();
    else if (key === "r" || key === "R") modes?.switchTo("select-range");
    else if (key === "i" || key === "I") openImages(s.selected);
    else if (key === "g" || key === "G") store.update(toggleGhost);
    else if (key === "f" || key === "F") fit();
    else if (key === "u" || key === "U") s.selected !== null && ctl.perform(actionUnmove(s.selected));
    else if (key === "Escape") {
      store.update((x) => dismissRefusal(select(x, null)));
      images.close();
    } else handled = false;
    if (handled) {
      e.preventDefault();
      e.stopPropagation();
      const sel = store.get().selected;
      if (sel !== null && sel !== s.selected) panTo(sel);
    }
  };
  window.addEventListener("keydown", onKey, true);
  cleanups.push(() => window.removeEventListener("keydown", onKey, true));

  ctl.load().then(
    () => {
      ctl.watch();
      const s = store.get();
      if (s.doc && s.doc.keyframes.some((k) => k.images.length)) {
        api.runImages(runId).then(
          (r) => (images.meta = new Map(r.items.map((im) => [String(im.id), im]))),
          () => undefined, // names and EXIF are extras; the images themselves still load
        );
      }
    },
    () => undefined,
  );
  render(store.get(), null);
  return () => cleanups.reverse().forEach((f) => f());
}

function refusalTitle(reason: string): string {
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
