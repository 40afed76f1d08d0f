/** Live step detection (samples one at a time) against the batch detection of a whole walk file. */
import { readFileSync, readdirSync } from "node:fs";
import { join, resolve } from "node:path";
import { describe, expect, it } from "vitest";
import { LiveSteps, headingFromEuler, headingFromQuaternion, headingFromRotationVector, parseWalk, stepsFromWalk } from "../src/tracker";

const DATA = resolve(__dirname, "../../data");
const walks = ["indoor-site1-F1", "indoor-site2-F2"].flatMap((f) => readdirSync(join(DATA, f, "walks")).map((w) => join(DATA, f, "walks", w)));

describe("live steps from samples one at a time", () => {
  for (const file of walks) {
    it(`${file.split("/").slice(-3).join("/")}: the batch steps, with their headings`, () => {
      const walk = parseWalk(readFileSync(file, "utf8"), file);
      const batch = stepsFromWalk(walk);
      const live = new LiveSteps(20); // a 20 s window: the buffer is trimmed on every walk here
      const got: { t_ms: number; heading_rad: number; freq_hz: number }[] = [];
      const a = walk.acc;
      const r = walk.rotvec;
      let j = 0;
      for (let i = 0; i < a.t.length; i++) {
        for (; j < r.t.length && r.t[j] <= a.t[i]; j++) live.addHeading(r.t[j], headingFromRotationVector(r.x[j], r.y[j], r.z[j]));
        live.addMotion(a.t[i], a.x[i], a.y[i], a.z[i]);
        got.push(...live.poll());
      }
      got.push(...live.poll(true));
      const bt = Array.from(batch.t_ms);
      const lt = got.map((s) => s.t_ms);
      const common = lt.filter((t) => bt.includes(t));
      // Live detection sees a cut buffer; it may differ by a step near an edge, never more.
      expect(Math.abs(lt.length - bt.length)).toBeLessThanOrEqual(1);
      expect(common.length).toBeGreaterThanOrEqual(bt.length - 1);
      for (const s of got) {
        const i = bt.indexOf(s.t_ms);
        if (i < 0) continue;
        expect(Math.abs(Math.atan2(Math.sin(s.heading_rad - batch.heading_rad[i]), Math.cos(s.heading_rad - batch.heading_rad[i])))).toBeLessThan(1e-9);
      }
      expect(new Set(lt).size).toBe(lt.length); // fed once
    });
  }

  it("headings of the three orientation sources agree for the same attitude", () => {
    // A phone flat, top pointing north-east: rotation about up by -45° from north-up.
    const alpha = -45; // deviceorientation: degrees CCW about up from north
    const q = [0, 0, Math.sin((alpha * Math.PI) / 360), Math.cos((alpha * Math.PI) / 360)];
    const h = Math.PI / 4;
    expect(headingFromQuaternion(q[0], q[1], q[2], q[3])).toBeCloseTo(h, 12);
    expect(headingFromEuler(alpha, 0)).toBeCloseTo(h, 12);
  });
});

describe("tapping the start on the floor view", async () => {
  const { fitView, fromPx, parseStart, toPx } = await import("../src/maps/floorView");
  it("fromPx inverts toPx, and the start field reads x,y or nothing", () => {
    const v = fitView(239.8, 176.4, 900, 660);
    const [px, py] = toPx(v, 81.3, 93.3);
    const [x, y] = fromPx(v, px, py);
    expect(x).toBeCloseTo(81.3, 9);
    expect(y).toBeCloseTo(93.3, 9);
    expect(parseStart(" 81.3, 93.3 ")).toEqual([81.3, 93.3]);
    for (const bad of ["", "81.3", "a,b", "1,2,3", "1,"]) expect(parseStart(bad)).toBeNull();
  });
});
