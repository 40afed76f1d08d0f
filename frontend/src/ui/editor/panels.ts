/** Small DOM panels of the correction view, each a pure function of editor state. */
import { OFFROAD_COLOR, STATUS_COLORS, STATUS_LABELS, SUGGESTION_COLOR } from "../../map/features";
import { type EditorState, type KeyframeStatus, currentDrift, currentEdits, currentSuggestions, editCount, keyframeStatuses } from "../../state/editor";
import { canRedo, canUndo, redoLabel, undoLabel } from "../../state/history";
import { h } from "../dom";
import type { Drift } from "../../state/types";

const ORDER: KeyframeStatus[] = ["adjustable", "fixed", "locked", "moved", "deleted", "flagged"];

export function legend(s: EditorState): HTMLElement {
  const counts = new Map<KeyframeStatus, number>();
  for (const st of keyframeStatuses(s)) counts.set(st, (counts.get(st) ?? 0) + 1);
  return h("div", { class: "legend", role: "group", "aria-label": "Legend" },
    h("strong", {}, "Keyframes"),
    h("ul", {}, ...ORDER.map((st) =>
      h("li", { "data-status": st },
        h("span", { class: "swatch", style: { background: STATUS_COLORS[st], opacity: st === "deleted" ? "0.5" : "1" } }),
        `${STATUS_LABELS[st]} `, h("span", { class: "muted" }, String(counts.get(st) ?? 0)),
      ),
    )),
    h("div", { class: "legend-line" }, h("span", { class: "line-swatch" }), "Corrected track (arrows: travel order)"),
    s.showGhost ? h("div", { class: "legend-line" }, h("span", { class: "line-swatch ghost" }), "Loaded revision (ghost)") : null,
    suggestionLegend(s),
  );
}

/** The suggestion layer's marks, while it is on the map. */
function suggestionLegend(s: EditorState): HTMLElement | null {
  const g = currentSuggestions(s);
  if (g.kind !== "ready" || !g.shown) return null;
  const ring = (color: string, fill: string) => h("span", { class: "swatch", style: { background: fill, boxShadow: `0 0 0 2px ${color}` } });
  return h("div", { "data-testid": "legend-suggestions" },
    h("strong", {}, "Suggestions"),
    h("ul", {},
      h("li", {}, ring(SUGGESTION_COLOR, "#fff"), "Suggested position (click to pick)"),
      h("li", {}, ring(SUGGESTION_COLOR, SUGGESTION_COLOR), "Accepted suggestion"),
      h("li", {}, ring(OFFROAD_COLOR, "transparent"), "Off-road keyframe")));
}

export function statusBar(s: EditorState): string {
  if (!s.doc) return "Loading…";
  const e = currentEdits(s);
  const parts = [
    `Revision ${s.doc.revision}`,
    `${editCount(e)} unsaved edit${editCount(e) === 1 ? "" : "s"}`,
    s.lastSolverTimeS === null ? "solver: —" : `last solver time ${(s.lastSolverTimeS * 1000).toFixed(0)} ms`,
  ];
  if (s.previewPending) parts.push("re-optimising…");
  if (s.mode !== "browse") parts.push(`mode: ${s.mode}`);
  const sub = s.submit;
  if (sub.kind === "sending") parts.push("submitting…");
  if (sub.kind === "waiting") parts.push(`correcting… ${Math.round(sub.progress * 100)}%`);
  return parts.join(" · ");
}

export interface ToolbarState {
  undo: { enabled: boolean; title: string };
  redo: { enabled: boolean; title: string };
  submitEnabled: boolean;
  hasSelection: boolean;
}

export function toolbarState(s: EditorState): ToolbarState {
  const busy = s.submit.kind === "sending" || s.submit.kind === "waiting";
  return {
    undo: { enabled: canUndo(s.history) && !busy, title: canUndo(s.history) ? `Undo: ${undoLabel(s.history)} (Ctrl+Z)` : "Nothing to undo" },
    redo: { enabled: canRedo(s.history) && !busy, title: canRedo(s.history) ? `Redo: ${redoLabel(s.history)} (Ctrl+Shift+Z)` : "Nothing to redo" },
    submitEnabled: !!s.doc && editCount(currentEdits(s)) > 0 && !busy && !s.conflict,
    hasSelection: s.selected !== null,
  };
}

export function selectionInfo(s: EditorState): HTMLElement {
  if (!s.doc || s.selected === null) return h("p", { class: "muted" }, "Select a keyframe (click, or keys . and ,).");
  const k = s.doc.keyframes[s.selected];
  const st = keyframeStatuses(s)[s.selected];
  const moved = currentEdits(s).moves.get(k.index);
  const p = moved ?? k.lonlat;
  return h("dl", { class: "kv", "data-testid": "selection-info" },
    h("dt", {}, "Keyframe"), h("dd", {}, `#${k.index}`),
    h("dt", {}, "Status"), h("dd", {}, STATUS_LABELS[st]),
    h("dt", {}, "Time"), h("dd", {}, formatRunTime(k.t_s, s.doc.keyframes[0]?.t_s ?? 0)),
    h("dt", {}, "Position"), h("dd", {}, `${p[1].toFixed(6)}, ${p[0].toFixed(6)}`),
    h("dt", {}, "Heading"), h("dd", {}, `${k.heading_deg.toFixed(0)}°`),
    h("dt", {}, "Images"), h("dd", {}, String(k.images.length)),
  );
}

export function driftInfo(s: EditorState): HTMLElement {
  const d = currentDrift(s);
  if (!d || (d.offset_m === null && !d.n_edits && !d.model)) {
    return h("p", { class: "muted", "data-testid": "drift" }, "No drift estimate yet: it needs moved keyframes.");
  }
  return h("p", { "data-testid": "drift" }, driftText(d));
}

/** The drift estimate in words, with the model the run's held-out edits chose. */
export function driftText(d: Drift): string {
  // the models without the drift model (plain, relative, naive) have no GNSS offset to tell
  const drift = d.model === null || d.model === "gnss" || d.model === "prior";
  return [
    !drift ? "" : d.detected === false ? "No GNSS drift detected" : d.offset_m !== null ? `GNSS offset ${d.offset_m.toFixed(1)} m` : "GNSS drift estimated",
    drift && d.spread_m !== null && Number.isFinite(d.spread_m) ? ` (spread ${d.spread_m.toFixed(1)} m)` : "",
    drift && d.max_bias_m !== null && d.max_bias_m > 0 ? `, largest bias ${d.max_bias_m.toFixed(1)} m` : "",
    drift && d.n_edits ? ` from ${d.n_edits} edit${d.n_edits === 1 ? "" : "s"}` : "",
    drift ? "." : "",
    d.model ? `${drift ? " " : ""}Model: ${d.model}` : "",
    d.model && d.cv_rmse_m !== null ? `, cross-validated RMSE ${d.cv_rmse_m.toFixed(2)} m at held-out edits` : "",
    d.model && d.predicted_rmse_m !== null ? `; predicted RMSE along the run ${d.predicted_rmse_m.toFixed(2)} m` : "",
    d.model ? "." : "",
  ].join("");
}

/** A keyframe time as seconds into the run, plus the clock time when `t_s` is a Unix time. */
export function formatRunTime(t_s: number, t0_s: number): string {
  const rel = `${(t_s - t0_s).toFixed(2)} s into the run`;
  // Times after 2001 are taken as Unix seconds (recorders log either those or seconds from start).
  if (t_s > 1e9) return `${rel} (${new Date(t_s * 1000).toISOString().replace("T", " ").slice(0, 19)} UTC)`;
  return rel;
}
