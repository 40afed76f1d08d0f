import { describe, expect, it } from "vitest";
import { loadDoc, perform, setPreview } from "../src/actions/editor";
import { actionMoveKeyframe } from "../src/actions/edits";
import { driftFrom } from "../src/api/convert";
import { currentDrift, currentEdits, editorNew } from "../src/state/editor";
import { driftText, formatRunTime, statusBar, toolbarState } from "../src/ui/editor/panels";
import { eastOf, straightDoc } from "./fixtures";

describe("status bar and toolbar", () => {
  const doc = straightDoc();
  const origin = doc.keyframes[0].reported;
  it("says revision, unsaved edits and the last solver time", () => {
    let s = loadDoc(editorNew(), doc);
    expect(statusBar(s)).toBe("Revision 1 · 0 unsaved edits · solver: —");
    s = perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = setPreview(s, currentEdits(s), doc.keyframes.map((k) => k.lonlat), 0.0234);
    expect(statusBar(s)).toBe("Revision 1 · 1 unsaved edit · last solver time 23 ms");
    const tb = toolbarState(s);
    expect(tb.undo).toEqual({ enabled: true, title: "Undo: Move keyframe 4 (Ctrl+Z)" });
    expect(tb.redo.enabled).toBe(false);
    expect(tb.submitEnabled).toBe(true);
    expect(toolbarState({ ...s, submit: { kind: "sending" } }).submitEnabled).toBe(false);
  });
  it("shows the preview's drift estimate while it is current", () => {
    let s = loadDoc(editorNew(), { ...doc, drift: driftFrom({ offset_enu_m: [null, null, null], spread_m: 0, n_edits: 0 }) });
    expect(currentDrift(s)?.offset_m).toBeNull();
    s = perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = setPreview(s, currentEdits(s), doc.keyframes.map((k) => k.lonlat), 0.01, driftFrom({ offset_enu_m: [6, 8, 0], spread_m: 1, detected: true, n_edits: 1, max_bias_m: 10 }));
    expect(currentDrift(s)).toEqual({ offset_m: 10, spread_m: 1, max_bias_m: 10, detected: true, n_edits: 1, model: null, cv_rmse_m: null, predicted_rmse_m: null });
  });
  it("names the model the edits chose and its cross-validated RMSE", () => {
    const drift = driftFrom({ offset_enu_m: [3, 4, null], spread_m: 1, detected: true, n_edits: 9,
      calibration: { model: "relative", cv_rmse_m: 1.234, predicted_rmse_m: 0.8 } });
    expect(drift?.model).toBe("relative");
    expect(driftText(drift!)).toBe("Model: relative, cross-validated RMSE 1.23 m at held-out edits; predicted RMSE along the run 0.80 m.");
    expect(driftText(driftFrom({ offset_enu_m: [3, 4, null], n_edits: 2, calibration: { model: "prior", cv_rmse_m: null } })!))
      .toBe("GNSS offset 5.0 m from 2 edits. Model: prior.");
    // a model without the drift model tells no GNSS offset
    expect(driftText(driftFrom({ offset_enu_m: [null, null, null], detected: false, n_edits: 0,
      calibration: { model: "naive", cv_rmse_m: 2.5, predicted_rmse_m: 1.5 } })!))
      .toBe("Model: naive, cross-validated RMSE 2.50 m at held-out edits; predicted RMSE along the run 1.50 m.");
  });
  it("formats run times relative to the start, with UTC for Unix times", () => {
    expect(formatRunTime(12.5, 2.5)).toBe("10.00 s into the run");
    expect(formatRunTime(1700000004, 1700000000)).toBe("4.00 s into the run (2023-11-14 22:13:24 UTC)");
  });
});

describe("plural", () => {
  it("puts the noun in the right number", async () => {
    const { plural } = await import("../src/ui/dom");
    expect(plural(1, "edit")).toBe("1 edit");
    expect(plural(0, "edit")).toBe("0 edits");
    expect(plural(2, "assignment")).toBe("2 assignments");
  });
});
