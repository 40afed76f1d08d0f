/**
 * The correction view: wires the store, the controller, the map adapter, the modes, the
 * keyboard behaviour and the DOM panels together. State flows one way:
 * input -> modes/controller -> store -> adapter/panels.
 */
import type { Map as MlMap } from "maplibre-gl";
import { dismissRefusal, nudgeSelected, select, selectNextAdjustable, selectStep, toggleGhost } from "../../actions/editor";
import { actionAcceptAsIs, actionMarkDeleted, actionReset, actionRestore, actionUnmove } from "../../actions/edits";
import { api } from "../../api/endpoints";
import { EDITOR_SHORTCUTS, type EditorCommand, installEditorKeys, nudgeVector } from "../../behaviors/keyboard";
import { MapAdapter } from "../../map/adapter";
import { createMap } from "../../map/createMap";
import { bounds } from "../../map/features";
import { SuggestionsPanel } from "../../maps/suggestPanel";
import { ModeManager } from "../../modes/manager";
import { type EditorState, correctionMagnitudes, currentEdits, displayPositions, editCount, keyframeStatuses } from "../../state/editor";
import type { AppContext } from "../context";
import { h } from "../dom";
import { keyCaps } from "../help";
import { basemapOptions, basemapSwitcher, initialBasemap, mapErrorMessage, showBasemap, zoomNote } from "./basemap";
import { CorrectionChart } from "./chart";
import { ConflictPanel } from "./conflict";
import { EditorController } from "./controller";
import { ExportMenu } from "./export";
import { FailedEditNotice } from "./failed";
import { ImagesPanel } from "./images";
import { ImageViewer } from "./imageViewer";
import { imageSequence } from "../../actions/images";
import { HistoryPanel } from "./history";
import { driftInfo, legend, selectionInfo, statusBar } from "./panels";
import { RangeConfirm } from "./rangeConfirm";
import { RefusalView } from "./refusal";
import { EditorToolbar, type SubmitOptions } from "./toolbar";
import { TourCard } from "./tour";

/** The side panel's key list, from the one shortcut table (the `?` overlay shows it all). */
function keysHelp(): HTMLElement {
  return h("ul", { class: "keys", "data-testid": "keys-help" },
    ...EDITOR_SHORTCUTS.filter((k) => !k.when).map((k) => h("li", {}, ...keyCaps(k.keys), ` ${k.what}`)),
    h("li", {}, h("kbd", {}, "←"), h("kbd", {}, "↑"), h("kbd", {}, "→"), h("kbd", {}, "↓"), " nudge the selected keyframe 0.5 m (", h("kbd", {}, "Shift"), " 5 m)"),
    h("li", {}, h("kbd", {}, "?"), " every shortcut"));
}

export function renderEditor(main: HTMLElement, app: AppContext, runId: string, onController?: (ctl: EditorController) => void, submitOpts?: SubmitOptions): () => void {
  const ctl = new EditorController(runId);
  onController?.(ctl);
  const store = ctl.store;
  const cleanups: (() => void)[] = [() => ctl.dispose()];
  let map: MlMap | null = null;
  let adapter: MapAdapter | null = null;
  let modes: ModeManager | null = null;
  let fitted = false;
  let closed = false;

  // ---- layout
  const notices = h("div", { class: "notices", role: "status", "aria-live": "polite", "data-testid": "notices" });
  // A notice speaks of the edits and revision shown when it was given: it leaves when they change.
  let noticeFor: { doc: unknown; edits: unknown } | null = null;
  const notify = (t: string) => {
    notices.replaceChildren(h("p", {}, t));
    const s = store.get();
    noticeFor = { doc: s.doc, edits: currentEdits(s) };
  };
  const suggest = new SuggestionsPanel(ctl, notify);
  cleanups.push(() => suggest.dispose());
  const exportMenu = new ExportMenu(runId);
  cleanups.push(() => exportMenu.dispose());
  const toolbar = new EditorToolbar({
    undo: () => ctl.undo(),
    redo: () => ctl.redo(),
    toggleDelete: () => toggleDeleteSelected(),
    toggleRange: () => modes?.switchTo(store.get().mode === "select-range" ? "browse" : "select-range"),
    acceptAsIs: () => ctl.perform(actionAcceptAsIs()),
    reset: () => ctl.perform(actionReset()),
    toggleGhost: () => store.update(toggleGhost),
    images: () => openImages(store.get().selected),
    fit: () => fit(),
    history: () => history.toggle(),
    submit: (comment) => void ctl.submit(comment).then(() => {
      if (editCount(currentEdits(store.get())) === 0) toolbar.comment.value = "";
    }),
  }, [exportMenu.el, ...suggest.elements], submitOpts);

  const mapEl = h("div", { class: "map", id: "map", "aria-label": "Map of the run; drag keyframes to correct them", role: "application", tabindex: "0" });
  const legendBox = h("div", { class: "legend-box" });
  const basemapBox = h("div", { class: "basemap-box" });
  const mapNote = h("div", { class: "map-note", role: "status", "data-testid": "map-note" });
  const zoomMsg = h("div", { class: "map-note zoom-note", role: "status", "data-testid": "zoom-note" });
  const mapWrap = h("div", { class: "map-wrap" }, mapEl, legendBox, basemapBox, mapNote, zoomMsg);

  const history = new HistoryPanel(ctl, store, app.user?.role ?? null);
  const selBox = h("div");
  const images = new ImagesPanel((kf, camera) => openViewer(kf, camera));
  const viewer = new ImageViewer((kf) => {
    store.update((x) => select(x, kf));
    followKeyframe(kf);
  }, () => map?.setPadding({ top: 0, bottom: 0, left: 0, right: 0 }));
  cleanups.push(() => viewer.dispose());
  const driftBox = h("div");
  const errorBox = h("div", { class: "error-box", role: "alert", "data-testid": "error", hidden: true });
  const tour = new TourCard((step) => {
    if (step) root.dataset.tourStep = step;
    else delete root.dataset.tourStep;
  });
  cleanups.push(() => tour.dispose());
  const side = h("aside", { class: "side", "aria-label": "Keyframe details" },
    tour.el,
    history.el,
    h("h2", {}, "Selected keyframe"), selBox,
    suggest.listEl,
    images.el,
    h("h2", {}, "Drift"), driftBox,
    h("h2", {}, "Keys"), keysHelp(),
    notices,
  );
  const chart = new CorrectionChart((i) => {
    store.update((s) => select(s, i));
    panTo(i);
  });
  const statusEl = h("div", { class: "statusbar", role: "status", "data-testid": "statusbar" });
  const submitMsg = h("span", { class: "submit-msg", "data-testid": "submit-msg" });
  const bottom = h("div", { class: "bottom" }, h("div", { class: "chart-wrap" }, h("span", { class: "chart-title" }, "Correction (m) along the run, band: predicted 1σ"), chart.canvas), h("div", { class: "status-row" }, statusEl, submitMsg));
  const conflict = new ConflictPanel({ reapply: () => void ctl.reloadAndReapply(), discard: () => void ctl.reloadDiscarding() });
  const rangeConfirm = new RangeConfirm();
  const refusal = new RefusalView(() => store.update(dismissRefusal));
  const failed = new FailedEditNotice(runId, notify);
  void failed.refresh().catch(() => undefined);  // the run itself loads (and reports errors) below
  const root = h("div", { class: "editor" }, toolbar.el, errorBox, failed.el, conflict.newerBox, h("div", { class: "editor-body" }, mapWrap, side), bottom, conflict.dialog, rangeConfirm.el, refusal.live);
  main.append(root);
  ctl.onNotice = notify;

  // ---- commands
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
      notify("Select a keyframe first to see its images.");
      return;
    }
    images.t0_s = s.doc.keyframes[0]?.t_s ?? 0;
    images.open(s.doc.keyframes[i], currentEdits(s).moves.get(i) ?? s.doc.keyframes[i].lonlat);
  }
  /** The larger view of the run's images, starting at keyframe `kf`'s camera `camera`. */
  function openViewer(kf: number, camera: number) {
    const s = store.get();
    if (!s.doc) return;
    viewer.meta = images.meta;
    if (!viewer.el.isConnected) mapWrap.append(viewer.el);
    viewer.open(imageSequence(s.doc), kf, camera);
    followKeyframe(kf);
  }
  /** Keep keyframe `i` in the part of the map the docked image view leaves visible. */
  function followKeyframe(i: number) {
    const s = store.get();
    if (!map || !s.doc) return;
    const right = viewer.isOpen ? viewer.el.offsetWidth + 16 : 0;
    map.easeTo({ center: displayPositions(s)[i] as [number, number], padding: { top: 0, bottom: 0, left: 0, right }, duration: 250 });
  }
  function toggleDeleteSelected() {
    const s = store.get();
    if (s.selected === null || !s.doc) return;
    ctl.perform(currentEdits(s).deleted.has(s.selected) ? actionRestore(s.selected) : actionMarkDeleted(s.selected));
  }
  function runCommand(c: EditorCommand) {
    const before = store.get();
    const nudge = nudgeVector(c);
    if (nudge) {
      store.update((x) => nudgeSelected(x, nudge[0], nudge[1]));
      if (before.selected !== null) panTo(before.selected);
      return;
    }
    switch (c) {
      case "undo": ctl.undo(); break;
      case "redo": ctl.redo(); break;
      case "next": store.update((x) => selectStep(x, +1)); break;
      case "previous": store.update((x) => selectStep(x, -1)); break;
      case "next-adjustable": store.update(selectNextAdjustable); break;
      case "toggle-delete": toggleDeleteSelected(); break;
      case "delete-range": modes?.switchTo("select-range"); break;
      case "images": openImages(before.selected); break;
      case "ghost": store.update(toggleGhost); break;
      case "fit": fit(); break;
      case "history": history.toggle(); break;
      case "unmove": if (before.selected !== null) ctl.perform(actionUnmove(before.selected)); break;
      case "suggestion-accept": suggest.acceptFocused(); break;
      case "suggestion-skip": suggest.skip(); break;
      case "suggestion-next": suggest.step(1); break;
      case "suggestion-previous": suggest.step(-1); break;
      case "escape":
        store.update((x) => dismissRefusal(select(x, null)));
        images.close();
        if (viewer.isOpen) viewer.close();
        rangeConfirm.close();
        break;
    }
    const sel = store.get().selected;
    if (sel !== null && sel !== before.selected) panTo(sel);
  }
  cleanups.push(installEditorKeys(window, () => store.get(), runCommand));

  // ---- map
  (async () => {
    const made = await createMap(mapEl, { navigation: true, scale: true, exposeAs: "__posefixMap", alive: () => !closed });
    if (!made) return;
    const { map: m, style, note } = made;
    map = m;
    if (note) mapNote.textContent = note;
    const opts = basemapOptions(style);
    let current = initialBasemap(style, opts);
    const label = () => opts.find((o) => o.source === current)?.label ?? null;
    const sayZoom = () => {
      zoomMsg.textContent = zoomNote(style, opts.find((o) => o.source === current), m.getZoom()) ?? "";
    };
    basemapBox.replaceChildren(basemapSwitcher(opts, current, (src) => {
      current = src;
      mapNote.textContent = note ?? "";
      if (map) showBasemap(map, opts, src);
      sayZoom();
    }));
    m.on("zoomend", sayZoom);
    m.on("error", (e) => {
      const msg = (e as unknown as { error?: { message?: string } }).error?.message ?? "";
      if (msg) mapNote.textContent = mapErrorMessage(msg, label());
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
        commitRange: (a, b) => rangeConfirm.ask(store.get(), a, b, () => ctl.commitRange(a, b)),
        openImages: (i) => openImages(i),
      });
      mapEl.dataset.ready = "true";
      sayZoom();
      render(store.get(), null);
    });
  })();
  cleanups.push(() => {
    closed = true;
    modes?.destroy();
    refusal.remove();
    map?.remove();
  });

  // ---- rendering
  let chartDeps: unknown[] = [];
  function render(s: EditorState, prev: EditorState | null) {
    if (adapter) adapter.render(s);
    if (map && s.doc && !fitted && mapEl.dataset.ready === "true") {
      fitted = true;
      fit(false);
    }
    toolbar.render(s);
    exportMenu.render(s.doc?.name ?? "", s.doc?.revision ?? null, editCount(currentEdits(s)));
    statusEl.textContent = statusBar(s);
    root.dataset.revision = String(s.doc?.revision ?? "");
    root.dataset.unsaved = String(editCount(currentEdits(s)));
    root.dataset.previewCurrent = String(!!s.preview && s.preview.forEdits === currentEdits(s));

    const sub = s.submit;
    const unsaved = editCount(currentEdits(s));
    submitMsg.textContent = sub.kind === "error" ? sub.message : sub.kind === "done" && unsaved === 0 ? `Saved as revision ${sub.revision}.` : "";
    submitMsg.className = `submit-msg ${sub.kind === "error" ? "error" : ""}`;
    errorBox.hidden = !s.error;
    errorBox.textContent = s.error ?? "";
    conflict.render(s, prev);
    if (noticeFor && (noticeFor.doc !== s.doc || noticeFor.edits !== currentEdits(s))) {
      noticeFor = null;
      notices.replaceChildren();
    }

    const heavy = !prev || prev.doc !== s.doc || currentEdits(prev) !== currentEdits(s) || prev.preview !== s.preview || prev.showGhost !== s.showGhost || prev.suggestions !== s.suggestions;
    if (heavy) {
      legendBox.replaceChildren(legend(s));
      driftBox.replaceChildren(driftInfo(s));
    }
    if (heavy || prev?.selected !== s.selected) selBox.replaceChildren(selectionInfo(s));
    const cd = [s.doc, currentEdits(s), s.preview, s.selected];
    if (cd.some((d, i) => d !== chartDeps[i])) {
      chartDeps = cd;
      const st = keyframeStatuses(s);
      chart.set({ now: correctionMagnitudes(s), before: s.doc ? s.doc.keyframes.map((k) => k.correction_m) : [], selected: s.selected, deleted: st.map((x) => x === "deleted"), sigma: s.doc ? s.doc.keyframes.map((k) => k.sigma_m) : [] });
    }
    if (prev?.selected !== s.selected && images.isOpen && s.selected !== null && s.doc) openImages(s.selected);
    if (!prev || prev.refusal !== s.refusal) refusal.show(s, map);
    if (prev) tour.update(s, prev);
    if (!prev || prev.doc?.rules !== s.doc?.rules) tour.show(s);
    if (prev && prev.doc?.revision !== s.doc?.revision && history.isOpen) void history.reload();
  }
  cleanups.push(store.subscribe((next, prev) => render(next, prev)));

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
