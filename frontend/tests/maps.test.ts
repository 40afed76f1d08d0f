import { describe, expect, it } from "vitest";
import { loadDoc, perform, undo } from "../src/actions/editor";
import { actionMoveKeyframe } from "../src/actions/edits";
import { editsBody, editsFromBody } from "../src/api/convert";
import { actionAcceptAllSuggestions, actionAcceptSuggestion, pending, suggestionsFC, suggestionsFrom, type Suggestion } from "../src/maps/suggestions";
import { currentEdits, editorNew } from "../src/state/editor";
import { eastOf, straightDoc } from "./fixtures";

const doc = straightDoc(); // every_n 2, lock_n 2 forward, max_move_m 30, keyframe k at 10·k m east
const origin = doc.keyframes[0].reported;
const loaded = () => loadDoc(editorNew(), doc);

function sug(index: number, north_m: number, extra: Partial<Suggestion> = {}): Suggestion {
  return { index, lonlat: eastOf(origin, index * 10, north_m), moved_m: Math.abs(north_m), off_road: false, sigma_m: 3, adjustable: index % 2 === 0, ...extra };
}

describe("suggestion actions", () => {
  it("accepting one stages a move marked as a suggestion, sent as kind suggestion", () => {
    const s = perform(loaded(), actionAcceptSuggestion(sug(4, 3)));
    expect(s.refusal).toBeNull();
    const e = currentEdits(s);
    expect(e.moves.get(4)).toEqual(sug(4, 3).lonlat);
    expect([...(e.suggested ?? [])]).toEqual([4]);
    const body = editsBody(e);
    expect(body.moves).toEqual([{ index: 4, lon: e.moves.get(4)![0], lat: e.moves.get(4)![1], kind: "suggestion" }]);
    // Kept in the browser and restored with its kind.
    expect([...(editsFromBody(body).suggested ?? [])]).toEqual([4]);
    expect(currentEdits(undo(s)).moves.size).toBe(0);
  });

  it("goes through the editing rules like any move", () => {
    const notAdjustable = perform(loaded(), actionAcceptSuggestion(sug(3, 3, { adjustable: true })));
    expect(notAdjustable.refusal?.reason).toBe("not_adjustable");
    const tooFar = perform(loaded(), actionAcceptSuggestion(sug(6, 45)));
    expect(tooFar.refusal?.reason).toBe("too_far");
    expect(currentEdits(tooFar).moves.size).toBe(0);
  });

  it("moving the keyframe by hand afterwards makes it an operator move", () => {
    let s = perform(loaded(), actionAcceptSuggestion(sug(4, 3)));
    s = perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 6)));
    expect(s.refusal).toBeNull();
    expect(currentEdits(s).suggested?.has(4)).toBe(false);
    expect(editsBody(currentEdits(s)).moves[0].kind).toBe("move");
  });

  it("accept all is one step that skips what the rules refuse", () => {
    // 4 locks 5 and 6 (lock_n 2 forward): 6 is skipped, 8 and 12 are accepted.
    const all = [sug(4, 2), sug(6, 2), sug(8, 2), sug(12, 50), sug(14, 4)];
    const action = actionAcceptAllSuggestions(all);
    const s = perform(loaded(), action);
    expect(s.refusal).toBeNull();
    expect([...currentEdits(s).moves.keys()].sort((a, b) => a - b)).toEqual([4, 8, 14]);
    expect(action.skipped.map((r) => [r.index, r.reason])).toEqual([[6, "locked"], [12, "too_far"]]);
    expect(s.history.steps.length).toBe(2);
    expect(pending(all, currentEdits(s)).map((x) => x.index)).toEqual([6, 12]);
    expect(currentEdits(undo(s)).moves.size).toBe(0);
  });

  it("accept all with nothing acceptable is refused, edits unchanged", () => {
    const s = perform(loaded(), actionAcceptAllSuggestions([sug(3, 2, { adjustable: true })]));
    expect(s.refusal?.message).toMatch(/No suggestion could be accepted/);
    expect(currentEdits(s).moves.size).toBe(0);
  });
});

describe("suggestion layer and parsing", () => {
  it("draws links for offered suggestions, marks accepted ones and off-road keyframes", () => {
    const items = [sug(0, 0.1), sug(2, 3, { off_road: true }), sug(4, 5)];
    const positions = doc.keyframes.map((k) => k.lonlat);
    const s = perform(loaded(), actionAcceptSuggestion(items[2]));
    const fc = suggestionsFC(items, positions, currentEdits(s));
    const kinds = fc.features.map((f) => `${f.properties!.kind}:${f.properties!.i ?? ""}`);
    expect(kinds).toEqual(["path:", "offroad:2", "link:2", "point:2", "point:4"]);
    expect(fc.features.find((f) => f.properties!.i === 4)!.properties!.accepted).toBe(true);
  });

  it("refuses an answer without items or positions", () => {
    expect(() => suggestionsFrom({})).toThrow(/no items/);
    expect(() => suggestionsFrom({ items: [{ index: 0, lon: "x", lat: 1 }] })).toThrow(/no position/);
    const ok = suggestionsFrom({ revision: 2, off_road: 1, time_ms: 5, items: [{ index: 0, lon: 24.9, lat: 60.1, moved_m: 1, off_road: true, sigma_m: 2, adjustable: true }] });
    expect(ok.items[0]).toEqual({ index: 0, lonlat: [24.9, 60.1], moved_m: 1, off_road: true, sigma_m: 2, adjustable: true });
    expect(ok.matcher).toBe("roads");
    expect(suggestionsFrom({ matcher: "grid", items: [] }).matcher).toBe("grid");
  });
});

describe("floor view geometry", () => {
  it("maps floor metres to canvas pixels (y up to y down) and sizes the 2σ ellipse", async () => {
    const { ellipsePx, fitView, reachedWaypoints, toPx } = await import("../src/maps/floorView");
    const v = fitView(200, 100, 420, 220, 10); // 2 px per metre, centred
    expect(v.scale).toBe(2);
    expect(toPx(v, 0, 0)).toEqual([10, 210]);
    expect(toPx(v, 200, 100)).toEqual([410, 10]);
    const step = { i: 0, t_ms: 0, x_m: 0, y_m: 0, dr_x_m: 0, dr_y_m: 0, sigma_major_m: 1.5, sigma_minor_m: 0.5, angle_deg: 90 };
    const e = ellipsePx(v, step);
    expect([e.rx, e.ry]).toEqual([6, 2]);
    expect(e.rotation).toBeCloseTo(-Math.PI / 2);
    const wp = (t: number) => ({ t_ms: t, x_m: 0, y_m: 0, error_m: 1, dr_error_m: 2, given_start: false });
    const track = { steps: [0, 100, 200].map((t, i) => ({ ...step, i, t_ms: t })), errors: { n: 3, mean_m: 1, median_m: 1, p95_m: 1, max_m: 1, skip_first: false, waypoints: [wp(0), wp(150), wp(260)] }, walk: { file: "w", n_steps: 2, start: "unknown", track_ms: 1, ms_per_step: 1 } };
    expect(reachedWaypoints(track, 0).length).toBe(1);
    expect(reachedWaypoints(track, 1).length).toBe(1);
    expect(reachedWaypoints(track, 2).length).toBe(3);
  });

  it("zooms to a walk: its box with a margin fills the canvas", async () => {
    const { fitBox, toPx, walkBox } = await import("../src/maps/floorView");
    const v = fitBox([10, 10, 30, 20], 420, 220, 10);
    expect(toPx(v, 10, 10)).toEqual([10, 210]);
    expect(toPx(v, 30, 20)).toEqual([410, 10]);
    const step = { i: 0, t_ms: 0, x_m: 50, y_m: 40, dr_x_m: 52, dr_y_m: 40, sigma_major_m: 1, sigma_minor_m: 1, angle_deg: 0 };
    const track = { steps: [step, { ...step, x_m: 100, dr_x_m: 104 }], errors: { n: 0, mean_m: null, median_m: null, p95_m: null, max_m: null, skip_first: false, waypoints: [] }, walk: { file: "w", n_steps: 1, start: "unknown", track_ms: 1, ms_per_step: 1 } };
    expect(walkBox(track, 5, 30)).toEqual([45, 25, 109, 55]);
  });

  it("places the floor on the map: by its georeference, else in its own metric frame", async () => {
    const { floorCorners, floorLonLat, walkFeatures } = await import("../src/maps/floorView");
    const geo = { georef: [24.9, 60.1, 1e-5, 5e-6], width_m: 40, height_m: 20 };
    expect(floorLonLat(geo, 10, 4)).toEqual([24.9 + 1e-4, 60.1 + 2e-5]);
    expect(floorCorners(geo)).toEqual([floorLonLat(geo, 0, 20), floorLonLat(geo, 40, 20), floorLonLat(geo, 40, 0), [24.9, 60.1]]);
    const local = { georef: null, width_m: 40, height_m: 20 };
    expect(floorLonLat(local, 111_320, 0)[0]).toBeCloseTo(1, 12);
    const step = { i: 0, t_ms: 0, x_m: 1, y_m: 2, dr_x_m: 1, dr_y_m: 2, sigma_major_m: 1, sigma_minor_m: 1, angle_deg: 0 };
    const track = { steps: [step, { ...step, x_m: 3 }, { ...step, x_m: 5 }], errors: { n: 0, mean_m: null, median_m: null, p95_m: null, max_m: null, skip_first: false, waypoints: [] }, walk: { file: "w", n_steps: 3, start: "unknown", track_ms: 1, ms_per_step: 1 } };
    const fc = walkFeatures(geo, track, 1);
    const matched = fc.features.find((f) => f.properties?.kind === "matched")!.geometry as GeoJSON.LineString;
    expect(matched.coordinates).toEqual([floorLonLat(geo, 1, 2), floorLonLat(geo, 3, 2)]);
    expect((fc.features.find((f) => f.properties?.kind === "position")!.geometry as GeoJSON.Point).coordinates).toEqual(floorLonLat(geo, 3, 2));
    expect(walkFeatures(geo, null, 0).features).toEqual([]);
  });
});
