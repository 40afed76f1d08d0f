import { describe, expect, it } from "vitest";
import { checkNewMove } from "../src/rules/apply";
import { distanceM, enuProjector } from "../src/rules/geodesy";
import { checkEdits, formatG, isAdjustable, lockSpan, lockedMask, ordinal } from "../src/rules/rules";
import { EMPTY_EDITS } from "../src/state/types";
import { RULES, eastOf, straightDoc } from "./fixtures";

describe("geodesy", () => {
  it("projects to ENU metres: 1e-4 deg of latitude is about 11.1 m at 60N", () => {
    const proj = enuProjector([24.94, 60.17]);
    const [e, n] = proj([24.94, 60.1701]);
    expect(Math.abs(e)).toBeLessThan(1e-6);
    expect(n).toBeCloseTo(11.16, 1);
    expect(distanceM([24.94, 60.17], [24.94, 60.1701])).toBeCloseTo(n, 3);
  });
  it("origin maps to zero", () => {
    expect(enuProjector([10, 50])([10, 50])).toEqual([0, 0]);
  });
});

describe("rules", () => {
  it("every_n marks adjustable keyframes", () => {
    expect([0, 1, 2, 3, 4].map((i) => isAdjustable(i, RULES))).toEqual([true, false, true, false, true]);
  });
  it("lock span forward and both", () => {
    expect(lockSpan(4, 10, RULES)).toEqual([5, 6]);
    expect(lockSpan(4, 10, { ...RULES, lock_direction: "both" })).toEqual([2, 3, 4, 5, 6]);
    expect(lockSpan(9, 10, RULES)).toEqual([]);
    expect(lockedMask(10, [4], { ...RULES, lock_direction: "both" }).map((b, i) => (b ? i : -1)).filter((i) => i >= 0)).toEqual([2, 3, 5, 6]);
  });
  it("refuses in the documented order", () => {
    const reported: [number, number][] = Array.from({ length: 10 }, (_, k) => [k * 10, 0]);
    const r = checkEdits(RULES, reported, [
      { index: 12, east_m: 0, north_m: 0 },
      { index: 1, east_m: 10, north_m: 1 },
      { index: 2, east_m: 20, north_m: 1 },
      { index: 2, east_m: 20, north_m: 2 },
      { index: 4, east_m: 40, north_m: 5 },
      { index: 8, east_m: 80, north_m: 31 },
      { index: 6, east_m: 60, north_m: 0 },
    ], [6]);
    expect(r.refusals.map((x) => [x.index, x.reason])).toEqual([
      [1, "not_adjustable"],
      [2, "duplicate"],
      [4, "locked"],
      [6, "deleted"],
      [8, "too_far"],
      [12, "out_of_range"],
    ]);
    expect(r.accepted.map((m) => m.index)).toEqual([2]);
  });
  it("order reversal is refused or flagged per order_rule", () => {
    const reported: [number, number][] = Array.from({ length: 10 }, (_, k) => [k * 10, 0]);
    const moves = [{ index: 2, east_m: 25, north_m: 0 }, { index: 6, east_m: 20, north_m: 0 }];
    const refuse = checkEdits({ ...RULES, max_move_m: 10000 }, reported, moves);
    expect(refuse.refusals.map((x) => [x.index, x.reason])).toEqual([[6, "order_reversed"]]);
    expect(refuse.accepted.map((m) => m.index)).toEqual([2]);
    const flag = checkEdits({ ...RULES, max_move_m: 10000, order_rule: "flag" }, reported, moves);
    expect(flag.refusals).toEqual([]);
    expect(flag.flags.map((x) => [x.index, x.reason])).toEqual([[6, "order_reversed"]]);
    expect(flag.accepted.map((m) => m.index)).toEqual([2, 6]);
  });
  it("max_move_m is always a limit (there is no 'unlimited')", () => {
    const r = checkEdits({ ...RULES, max_move_m: 0 }, [[0, 0], [10, 0]], [{ index: 0, east_m: 0, north_m: 5000 }]);
    expect(r.refusals.map((x) => x.reason)).toEqual(["too_far"]);
  });
  it("formats limits like Python's :g", () => {
    expect(formatG(30)).toBe("30");
    expect(formatG(12.5)).toBe("12.5");
  });
});

describe("rules on lon/lat docs", () => {
  const doc = straightDoc();
  const origin = doc.keyframes[0].reported;
  it("allows a small move of an adjustable keyframe", () => {
    expect(checkNewMove(doc, EMPTY_EDITS, 4, eastOf(origin, 40, 5))).toBeNull();
  });
  it("refuses a move beyond max_move_m with the distance", () => {
    const r = checkNewMove(doc, EMPTY_EDITS, 4, eastOf(origin, 40, 35));
    expect(r?.reason).toBe("too_far");
    expect(r?.message).toMatch(/35\.0 m; the limit is 30 m/);
  });
  it("refuses a keyframe locked by an earlier move in the batch", () => {
    const edits = { ...EMPTY_EDITS, moves: new Map([[4, eastOf(origin, 40, 3)]]) };
    // 6 is within lock_n=2 after 4
    expect(checkNewMove(doc, edits, 6, eastOf(origin, 60, 3))?.reason).toBe("locked");
  });
  it("refuses a new lower move that would lock an earlier one, worded from the new move", () => {
    const edits = { ...EMPTY_EDITS, moves: new Map([[6, eastOf(origin, 60, 3)]]) };
    const r = checkNewMove(doc, edits, 4, eastOf(origin, 40, 3));
    expect(r?.index).toBe(4);
    expect(r?.reason).toBe("locked");
    expect(r?.message).toMatch(/Moving keyframe 4 would break an earlier move/);
  });
  it("earlier revisions' edits lock their neighbours", () => {
    const d2 = straightDoc();
    d2.keyframes[4] = { ...d2.keyframes[4], edited: true };
    expect(checkNewMove(d2, EMPTY_EDITS, 6, eastOf(origin, 60, 1))?.reason).toBe("locked");
  });
});

describe("messages", () => {
  it("read as English for any count, as the server's do", () => {
    const en: [number, number][] = [[0, 0], [10, 0], [20, 0], [30, 0]];
    const base = { ...RULES, lock_n: 1, every_n: 2, max_move_m: 1000 };
    expect(checkEdits(base, en, [{ index: 1, east_m: 10, north_m: 1 }]).refusals[0].message).toContain("every 2nd keyframe");
    const locked = checkEdits({ ...base, every_n: 1 }, en, [{ index: 2, east_m: 20, north_m: 1 }], [], new Map([[1, [10, 1] as const]]));
    expect(locked.refusals[0].message).toContain("within 1 keyframe of");
    expect([1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111].map(ordinal)).toEqual(["1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st", "111th"]);
  });
});
