import { describe, expect, it } from "vitest";
import { loadDoc, perform } from "../src/actions/editor";
import { actionMoveKeyframe } from "../src/actions/edits";
import { filmstripWindow, imageAt, imageSequence, stepImage, stepKeyframe } from "../src/actions/images";
import { refusalHint, tourAdvance } from "../src/actions/tour";
import { EDITOR_COMMANDS, EDITOR_SHORTCUTS, editorCommand, parseKeys } from "../src/behaviors/keyboard";
import { focusAfterAccept, focusSuggestion, skipSuggestion, stepSuggestion, suggestionsReady, todo, actionAcceptSuggestion } from "../src/maps/suggestions";
import { currentEdits, editorNew } from "../src/state/editor";
import type { Suggestion } from "../src/state/types";
import { REVIEW_SHORTCUTS, reviewCommand } from "../src/tasks/format";
import { comparatorsFor, qualificationNames, requirementValue, runAt, runMapFocus } from "../src/tasks/taskForm";
import { exportLinks } from "../src/ui/editor/export";
import { RULES, eastOf, straightDoc } from "./fixtures";

describe("export links", () => {
  it("point at the shown revision in each format, with a file name", () => {
    const links = exportLinks("7", "Drive: Kamppi / 2", 3);
    expect(links.map((l) => l.href)).toEqual([
      "/api/v1/runs/7/export?format=csv&revision=3",
      "/api/v1/runs/7/export?format=gpx&revision=3",
      "/api/v1/runs/7/export?format=geojson&revision=3",
    ]);
    expect(links.map((l) => l.filename)).toEqual(["Drive_Kamppi_2-r3.csv", "Drive_Kamppi_2-r3.gpx", "Drive_Kamppi_2-r3.geojson"]);
  });
});

describe("shortcut tables", () => {
  const doc = straightDoc();
  const withSuggestions = { conflict: null, mode: "browse" as const, selected: 3, doc,
    suggestions: { kind: "ready" as const, revision: doc.revision, items: [], offRoad: 0, timeMs: 0, matcher: "roads", focus: null, skipped: new Set<number>(), shown: true } };
  it("every editor command is listed, and every listed key does what the table says", () => {
    expect(new Set(EDITOR_SHORTCUTS.map((r) => r.command))).toEqual(new Set(EDITOR_COMMANDS));
    for (const row of EDITOR_SHORTCUTS) {
      for (const k of row.keys) expect([k, editorCommand(parseKeys(k), withSuggestions)]).toEqual([k, row.command]);
    }
  });
  it("suggestion keys do nothing while suggestions are hidden or absent", () => {
    const hidden = { ...withSuggestions, suggestions: { ...withSuggestions.suggestions, shown: false } };
    expect(editorCommand(parseKeys("Enter"), hidden)).toBeNull();
    expect(editorCommand(parseKeys("S"), { conflict: null, mode: "browse", selected: null })).toBeNull();
  });
  it("the review table matches the review keys", () => {
    for (const row of REVIEW_SHORTCUTS) for (const k of row.keys) expect(reviewCommand({ ...parseKeys(k), altKey: false })).toBe(row.command);
    expect(reviewCommand({ key: "a", ctrlKey: true, metaKey: false })).toBeNull();
  });
});

describe("suggestions: picking never accepts; accept and skip step through", () => {
  const doc = straightDoc(20);
  const sug = (index: number, m: number): Suggestion => ({ index, lonlat: eastOf(doc.keyframes[index].lonlat, 0, m), moved_m: m, off_road: false, sigma_m: 1, adjustable: true });
  const items = [sug(2, 3), sug(6, 4), sug(10, 0.2), sug(14, 5)];
  const s0 = loadDoc(editorNew(), doc);
  const ready = suggestionsReady({ revision: doc.revision, items, offRoad: 0, timeMs: 1, matcher: "roads" }, currentEdits(s0));
  it("focuses the first one to decide", () => {
    expect(ready.focus).toBe(2);
    expect(todo(ready, currentEdits(s0)).map((s) => s.index)).toEqual([2, 6, 14]);
  });
  it("focus and step change the pick only", () => {
    expect(focusSuggestion(ready, 14).focus).toBe(14);
    expect(focusSuggestion(ready, 10).focus).toBe(2); // not offered (under 0.5 m)
    expect(stepSuggestion(ready, 1).focus).toBe(6);
    expect(stepSuggestion(focusSuggestion(ready, 14), 1).focus).toBe(14);
    expect(stepSuggestion(ready, -1).focus).toBe(2);
  });
  it("skip leaves it out and picks the next; accept picks the next to decide", () => {
    const sk = skipSuggestion(ready, currentEdits(s0));
    expect(sk.focus).toBe(6);
    expect(todo(sk, currentEdits(s0)).map((s) => s.index)).toEqual([6, 14]);
    const s1 = perform(s0, actionAcceptSuggestion(items[1]));
    expect(currentEdits(s1).suggested?.has(6)).toBe(true);
    expect(focusAfterAccept(sk, currentEdits(s1)).focus).toBe(14);
    const all = skipSuggestion(skipSuggestion(sk, currentEdits(s1)), currentEdits(s1));
    expect(all.focus).toBeNull();
  });
});

describe("tour", () => {
  const doc = straightDoc();
  const s0 = loadDoc(editorNew(), doc);
  it("advances on a drag, then a refusal, then a finished submit", () => {
    const s1 = perform(s0, actionMoveKeyframe(4, eastOf(doc.keyframes[4].lonlat, 0, 5)));
    expect(tourAdvance("drag", s0, s0)).toBe("drag");
    expect(tourAdvance("drag", s0, s1)).toBe("refusal");
    const s2 = perform(s1, actionMoveKeyframe(5, eastOf(doc.keyframes[5].lonlat, 0, 5))); // 5 is not adjustable
    expect(s2.refusal).not.toBeNull();
    expect(tourAdvance("refusal", s1, s2)).toBe("submit");
    const sending = { ...s2, submit: { kind: "sending" as const } };
    expect(tourAdvance("submit", s2, sending)).toBe("submit");
    expect(tourAdvance("submit", sending, { ...sending, submit: { kind: "done" as const, revision: 2 } })).toBe("done");
    expect(tourAdvance("submit", sending, { ...sending, submit: { kind: "error" as const, message: "x" } })).toBe("submit");
  });
  it("says how to meet a refusal under the run's rules", () => {
    expect(refusalHint(RULES)).toContain("locked");
    expect(refusalHint({ ...RULES, lock_n: 0 })).toContain("one keyframe in 2");
    expect(refusalHint({ ...RULES, lock_n: 0, every_n: 1 })).toContain("more than 30 m");
    // the default limit (1 km) cannot be met by a drag on screen: the order rule can
    expect(refusalHint({ ...RULES, lock_n: 0, every_n: 1, max_move_m: 1000 })).toContain("backwards");
  });
});

describe("image sequence", () => {
  const doc = straightDoc(6);
  doc.keyframes[0].images = ["a", "b"];
  doc.keyframes[3].images = ["c", "d"];
  doc.keyframes[5].images = ["e"];
  const seq = imageSequence(doc);
  it("lists every camera of every keyframe in order", () => {
    expect(seq.map((x) => `${x.keyframe}:${x.camera}/${x.cameras}`)).toEqual(["0:0/2", "0:1/2", "3:0/2", "3:1/2", "5:0/1"]);
    expect(imageAt(seq, 3, 1)).toBe(3);
    expect(imageAt(seq, 1)).toBe(2); // no images at 1: the next keyframe that has some
  });
  it("steps by image and by keyframe, stopping at the ends", () => {
    expect(stepImage(seq, 4, 1)).toBe(4);
    expect(stepImage(seq, 0, -1)).toBe(0);
    expect(stepKeyframe(seq, 0, 1)).toBe(2);
    expect(stepKeyframe(seq, 3, -1)).toBe(0);
    expect(stepKeyframe(seq, 4, -1)).toBe(2);
    expect(stepKeyframe(seq, 4, 1)).toBe(4);
  });
  it("keeps the filmstrip window inside the run", () => {
    expect(filmstripWindow(100, 0, 11)).toEqual([0, 11]);
    expect(filmstripWindow(100, 50, 11)).toEqual([45, 56]);
    expect(filmstripWindow(100, 99, 11)).toEqual([89, 100]);
    expect(filmstripWindow(5, 3, 11)).toEqual([0, 5]);
  });
});

describe("task form", () => {
  const hel = { id: 1, bbox: [24.9, 60.1, 25.0, 60.2], created_at: "2026-01-01T00:00:00Z" };
  const hel2 = { id: 2, bbox: [24.93, 60.15, 24.95, 60.17], created_at: "2026-01-02T00:00:00Z" };
  const far = { id: 3, bbox: [139.7, 35.6, 139.8, 35.7], created_at: "2026-01-03T00:00:00Z" };
  it("fits the selected runs, else the saved view, else the newest run's region, never the world", () => {
    expect(runMapFocus([hel, hel2, far], new Set([1, 2]), null)).toEqual({ kind: "box", box: [24.9, 60.1, 25.0, 60.2] });
    expect(runMapFocus([hel, hel2, far], new Set(), { center: [24.9, 60.1], zoom: 11 })).toEqual({ kind: "view", center: [24.9, 60.1], zoom: 11 });
    expect(runMapFocus([hel, hel2, far], new Set(), null)).toEqual({ kind: "box", box: far.bbox });
    expect(runMapFocus([hel, hel2], new Set(), null)).toEqual({ kind: "box", box: hel.bbox });
    expect(runMapFocus([], new Set(), null)).toBeNull();
  });
  it("a click picks the smallest run outline under it", () => {
    expect(runAt([hel, hel2, far], 24.94, 60.16)).toBe(2);
    expect(runAt([hel, hel2, far], 24.91, 60.11)).toBe(1);
    expect(runAt([hel, hel2, far], 0, 0)).toBeNull();
    expect(runAt([hel, far], 24.899, 60.15)).toBeNull();
    expect(runAt([hel, far], 24.899, 60.15, [0.002, 0.001])).toBe(1); // on the outline, give or take a few pixels
    expect(runAt([hel, { ...hel, id: 9 }], 24.95, 60.15)).toBe(9); // equal outlines: the newest
  });
  it("offers known qualifications, the comparators the server takes, and checks values", () => {
    expect(qualificationNames([{ qualifications: [{ name: "night_driving" }, { name: "approved_count" }] }, { qualifications: [{ name: "lidar" }] }]))
      .toEqual(["approved_count", "accuracy_m", "home_area", "qualification_test", "lidar", "night_driving"]);
    expect(comparatorsFor("home_area")).toEqual(["contains"]);
    expect(comparatorsFor("accuracy_m")).not.toContain("exists");
    expect(requirementValue("ge", "5")).toEqual({ value: 5 });
    expect(requirementValue("in", "1, 2")).toEqual({ value: [1, 2] });
    expect(requirementValue("exists", "whatever")).toEqual({ value: null });
    expect("error" in requirementValue("ge", "")).toBe(true);
  });
});
