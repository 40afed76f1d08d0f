import { describe, expect, it } from "vitest";
import { loadDoc, perform, setPreview, stageDrag, toggleGhost } from "../src/actions/editor";
import { actionMarkDeleted, actionMoveKeyframe } from "../src/actions/edits";
import { bounds, ghostFC, keyframesFC, refusalFC, stagingFC, trackFC } from "../src/map/features";
import { canTransition } from "../src/modes/types";
import { currentEdits, editorNew } from "../src/state/editor";
import { eastOf, straightDoc } from "./fixtures";

const doc = straightDoc(10);
const origin = doc.keyframes[0].reported;

describe("GeoJSON for the map adapter", () => {
  it("keyframes carry index, heading and status; the track skips deleted keyframes", () => {
    let s = loadDoc(editorNew(), doc);
    s = perform(s, actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    s = perform(s, actionMarkDeleted(8));
    const kf = keyframesFC(s);
    expect(kf.features).toHaveLength(10);
    expect(kf.features[4].properties).toEqual({ i: 4, h: 90, s: "moved" });
    expect(kf.features[5].properties?.s).toBe("locked");
    expect((kf.features[4].geometry as GeoJSON.Point).coordinates).toEqual([...eastOf(origin, 40, 5)]);
    const line = trackFC(s).features[0].geometry as GeoJSON.LineString;
    expect(line.coordinates).toHaveLength(9);
  });
  it("the ghost is the loaded revision and can be hidden", () => {
    const s = loadDoc(editorNew(), doc);
    expect((ghostFC(s).features[0].geometry as GeoJSON.LineString).coordinates).toHaveLength(10);
    expect(ghostFC(toggleGhost(s)).features).toHaveLength(0);
  });
  it("the preview positions replace the drawn ones when current", () => {
    let s = perform(loadDoc(editorNew(), doc), actionMoveKeyframe(4, eastOf(origin, 40, 5)));
    const shifted = doc.keyframes.map((k) => [k.lonlat[0], k.lonlat[1] + 1e-5] as const);
    s = setPreview(s, currentEdits(s), shifted, 0.01);
    expect((keyframesFC(s).features[0].geometry as GeoJSON.Point).coordinates).toEqual([...shifted[0]]);
  });
  it("staging draws the dragged point and a line back; a refusal is drawn where dropped", () => {
    const s0 = loadDoc(editorNew(), doc);
    const s = stageDrag(s0, 2, eastOf(origin, 20, 3));
    const st = stagingFC(s);
    expect(st.features.map((f) => f.properties?.kind)).toEqual(["rubber", "point"]);
    const at = eastOf(origin, 30, 2);
    const r = perform(s0, actionMoveKeyframe(3, at), at);
    expect((refusalFC(r).features[0].geometry as GeoJSON.Point).coordinates).toEqual([...at]);
    expect(refusalFC(s0).features).toHaveLength(0);
  });
  it("bounds cover the run", () => {
    const b = bounds(loadDoc(editorNew(), doc))!;
    expect(b[0]).toBeCloseTo(origin[0]);
    expect(b[2]).toBeGreaterThan(b[0]);
  });
});

describe("modes", () => {
  it("allow only browse <-> drag and browse <-> select-range", () => {
    expect(canTransition("browse", "drag")).toBe(true);
    expect(canTransition("drag", "browse")).toBe(true);
    expect(canTransition("browse", "select-range")).toBe(true);
    expect(canTransition("drag", "select-range")).toBe(false);
    expect(canTransition("select-range", "drag")).toBe(false);
  });
});
