import { describe, expect, it } from "vitest";
import { loadDoc, nudgeSelected, perform, redo, select, selectNextAdjustable, selectStep, setPreview, stageDrag, undo } from "../src/actions/editor";
import { offsetEnM } from "../src/rules/geodesy";
import { actionAcceptAsIs, actionMarkDeleted, actionMoveKeyframe, actionReset, actionRestore, actionUnmove } from "../src/actions/edits";
import { editsBody, editsFromBody, docFromKeyframes, driftFrom } from "../src/api/convert";
import { currentEdits, displayPositions, editCount, editorNew, keyframeStatuses, previewIsCurrent } from "../src/state/editor";
import { canRedo, canUndo, historyNew, historyPerform, redoLabel, undoLabel } from "../src/state/history";
import { Store } from "../src/state/store";
import { EMPTY_EDITS } from "../src/state/types";
import { eastOf, straightDoc } from "./fixtures";

const doc = straightDoc();
const origin = doc.keyframes[0].reported;
const loaded = () => loadDoc(editorNew(), doc);

describe("history", () => {
  it("labels steps and drops the redo tail on a new step", () => {
    let h = historyNew();
    h = historyPerform(h, "a", EMPTY_EDITS);
    h = historyPerform(h, "b", EMPTY_EDITS);
    expect(undoLabel(h)).toBe("b");
    h = { ...h, at: 1 };
    expect(redoLabel(h)).toBe("b");
    h = historyPerform(h, "c", EMPTY_EDITS);
    expect(h.steps.map((s) => s.label)).toEqual(["Start", "a", "c"]);
    expect(canRedo(h)).toBe(false);
  });
});

describe("edit actions", () => {
  it("a move is one labelled, undoable step", () => {
    let s = perform(loaded(), actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    expect(s.refusal).toBeNull();
    expect(currentEdits(s).moves.get(4)).toBeDefined();
    expect(undoLabel(s.history)).toBe("Move keyframe 4");
    s = undo(s);
    expect(currentEdits(s).moves.size).toBe(0);
    expect(canUndo(s.history)).toBe(false);
    s = redo(s);
    expect(currentEdits(s).moves.size).toBe(1);
  });
  it("a refused move leaves edits and history alone and places the refusal where dropped", () => {
    const s0 = loaded();
    const at = eastOf(origin, 30, 1);
    const s = perform(s0, actionMoveKeyframe(3, at), at);
    expect(s.history).toBe(s0.history);
    expect(s.refusal?.reason).toBe("not_adjustable");
    expect(s.refusal?.at).toEqual(at);
  });
  it("staging does not touch edits", () => {
    const s0 = loaded();
    const s = stageDrag(s0, 4, eastOf(origin, 40, 5));
    expect(s.history).toBe(s0.history);
    expect(s.staging?.index).toBe(4);
    expect(perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 5))).staging).toBeNull();
  });
  it("delete a range and restore part of it; deletion drops a move", () => {
    let s = perform(loaded(), actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = perform(s, actionMarkDeleted(5, 3));
    expect([...currentEdits(s).deleted].sort()).toEqual([3, 4, 5]);
    expect(currentEdits(s).moves.has(4)).toBe(false);
    expect(undoLabel(s.history)).toBe("Delete keyframes 3–5");
    s = perform(s, actionRestore(4));
    expect([...currentEdits(s).deleted].sort()).toEqual([3, 5]);
    expect(perform(s, actionMarkDeleted(30)).refusal?.reason).toBe("out_of_range");
  });
  it("accept as is clears edits; reset is undoable; unmove", () => {
    let s = perform(loaded(), actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = perform(s, actionUnmove(4));
    expect(currentEdits(s).moves.size).toBe(0);
    s = perform(s, actionAcceptAsIs());
    expect(currentEdits(s).accept).toBe(true);
    expect(editCount(currentEdits(s))).toBe(1);
    s = perform(s, actionMoveKeyframe(8, eastOf(origin, 80, 5)));
    expect(currentEdits(s).accept).toBe(false);
    s = perform(s, actionReset());
    expect(editCount(currentEdits(s))).toBe(0);
    expect(editCount(currentEdits(undo(s)))).toBe(1);
  });
});

describe("keyboard nudges", () => {
  const offset = (s: ReturnType<typeof loaded>, i: number) => offsetEnM(doc.keyframes[i].lonlat, currentEdits(s).moves.get(i)!);
  it("move the selected keyframe by metres, one undo step for consecutive nudges of it", () => {
    let s = select(loaded(), 4);
    s = nudgeSelected(s, 0.5, 0);
    s = nudgeSelected(s, 0.5, 0);
    s = nudgeSelected(s, 0, 5);
    const [e, n] = offset(s, 4);
    expect(e).toBeCloseTo(1.0, 3);
    expect(n).toBeCloseTo(5.0, 3);
    expect(s.history.steps.map((x) => x.label)).toEqual(["Start", "Nudge keyframe 4"]);
    expect(editCount(currentEdits(undo(s)))).toBe(0);
    s = select(nudgeSelected(select(s, 0), 0, 0.5), 4);
    s = nudgeSelected(s, 0.5, 0);
    expect(s.history.steps.map((x) => x.label)).toEqual(["Start", "Nudge keyframe 4", "Nudge keyframe 0", "Nudge keyframe 4"]);
  });
  it("are refused by the rules as a drag is, where the keyframe would go", () => {
    const s = nudgeSelected(select(loaded(), 3), 0.5, 0);
    expect(s.refusal?.reason).toBe("not_adjustable");
    expect(offsetEnM(doc.keyframes[3].lonlat, s.refusal!.at)[0]).toBeCloseTo(0.5, 3);
    expect(nudgeSelected(loaded(), 0.5, 0)).toEqual(loaded());
  });
});

describe("derived state", () => {
  it("statuses: moved, locked by lock_n, deleted, fixed, adjustable, flagged", () => {
    const d = straightDoc();
    d.keyframes[10] = { ...d.keyframes[10], flagged: true };
    let s = loadDoc(editorNew(), d);
    s = perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = perform(s, actionMarkDeleted(12));
    const st = keyframeStatuses(s);
    expect(st.slice(0, 7)).toEqual(["adjustable", "fixed", "adjustable", "fixed", "moved", "locked", "locked"]);
    expect(st[10]).toBe("flagged");
    expect(st[12]).toBe("deleted");
  });
  it("displays the preview only when it was computed for the current edits", () => {
    let s = perform(loaded(), actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    const e = currentEdits(s);
    const positions = doc.keyframes.map((k) => [k.lonlat[0], k.lonlat[1] + 1e-5] as const);
    s = setPreview(s, e, positions, 0.012);
    expect(previewIsCurrent(s)).toBe(true);
    expect(displayPositions(s)[0]).toEqual(positions[0]);
    expect(s.lastSolverTimeS).toBe(0.012);
    s = undo(s);
    expect(previewIsCurrent(s)).toBe(false);
    expect(displayPositions(s)[0]).toEqual(doc.keyframes[0].lonlat);
  });
  it("keyboard selection: next/previous clamp, next adjustable wraps", () => {
    let s = selectStep(loaded(), 1);
    expect(s.selected).toBe(0);
    s = selectStep(s, -1);
    expect(s.selected).toBe(0);
    s = selectNextAdjustable(s);
    expect(s.selected).toBe(2);
    s = { ...s, selected: 18 };
    expect(selectNextAdjustable(s).selected).toBe(0);
  });
});

describe("store", () => {
  it("notifies only on change", () => {
    const st = new Store(1);
    const seen: number[] = [];
    st.subscribe((n) => seen.push(n));
    st.update((x) => x);
    st.update((x) => x + 1);
    expect(seen).toEqual([2]);
  });
});

describe("API conversions", () => {
  it("parses the keyframes GeoJSON and round-trips edits", () => {
    const fc = {
      type: "FeatureCollection",
      revision: 3,
      rules: { every_n: 5, lock_n: 3 },
      drift: { offset_enu_m: [3, 4, 0], spread_m: 1.5 },
      features: [0, 1].map((i) => ({
        type: "Feature",
        geometry: { type: "Point", coordinates: [24.9 + i * 1e-4, 60.1] },
        properties: { index: i, t: i * 0.5, heading_deg: 45, adjustable: i === 0, locked: false, edited: false, deleted: false, flagged: false, has_images: true, images: [7], reported: [24.9, 60.1], correction_m: 2, sigma_m: i === 0 ? 1.25 : null },
      })),
    };
    const d = docFromKeyframes("9", "drive", fc);
    expect(d.revision).toBe(3);
    expect(d.rules.every_n).toBe(5);
    expect(d.rules.order_rule).toBe("flag");
    expect(d.keyframes[1].lonlat[0]).toBeCloseTo(24.9001);
    expect(d.keyframes[0].images).toEqual(["7"]);
    expect(d.keyframes.map((k) => k.sigma_m)).toEqual([1.25, null]);
    expect(driftFrom(fc.drift)?.offset_m).toBe(5);
    const e = { moves: new Map([[5, [1, 2] as const], [0, [3, 4] as const]]), deleted: new Set([9, 2]), accept: false };
    const b = editsBody(e);
    expect(b.moves.map((m) => m.index)).toEqual([0, 5]);
    expect(b.deleted).toEqual([2, 9]);
    expect(editsBody(editsFromBody(b))).toEqual(b);
  });
  it("refuses out-of-order keyframes", () => {
    expect(() => docFromKeyframes("1", "x", { features: [{ geometry: { coordinates: [0, 0] }, properties: { index: 3 } }] })).toThrow(/in order/);
  });
});
