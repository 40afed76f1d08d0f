/**
 * The engine's edit rules, checked against the same vectors pytest reads
 * (tests/vectors/edit_rules.json; schema in its README), so the browser refuses exactly what
 * the server refuses. Reasons, indices and order are compared; messages are for people.
 */
import { readFileSync } from "node:fs";
import { resolve } from "node:path";
import { describe, expect, it } from "vitest";
import { type EnM, type KeyframeMove, checkEdits, isAdjustable, lockedMask, rulesFromJson } from "../src/rules/rules";

interface Case {
  name: string;
  rules: Record<string, unknown>;
  keyframes_en_m: [number, number][];
  edited_before: KeyframeMove[];
  moves: KeyframeMove[];
  deleted: number[];
  expected: {
    adjustable: boolean[];
    locked: boolean[];
    accepted: number[];
    refusals: { index: number; reason: string }[];
    flags: { index: number; reason: string }[];
  };
}

const path = resolve(__dirname, "../../tests/vectors/edit_rules.json");
const cases: Case[] = JSON.parse(readFileSync(path, "utf8")).cases;
const pick = (rs: { index: number; reason: string }[]) => rs.map((r) => ({ index: r.index, reason: r.reason }));

describe("edit rules vectors (tests/vectors/edit_rules.json)", () => {
  it("has cases covering every reason", () => {
    const reasons = new Set(cases.flatMap((c) => [...c.expected.refusals, ...c.expected.flags].map((r) => r.reason)));
    expect(cases.length).toBeGreaterThan(5);
    for (const r of ["out_of_range", "duplicate", "deleted", "not_adjustable", "locked", "too_far", "order_reversed"]) expect(reasons).toContain(r);
  });
  for (const c of cases) {
    it(c.name, () => {
      const rules = rulesFromJson(c.rules as never);
      const k = c.keyframes_en_m.length;
      const edited = new Map<number, EnM>(c.edited_before.map((e) => [e.index, [e.east_m, e.north_m]]));
      expect(Array.from({ length: k }, (_, i) => isAdjustable(i, rules))).toEqual(c.expected.adjustable);
      expect(lockedMask(k, edited.keys(), rules)).toEqual(c.expected.locked);
      const got = checkEdits(rules, c.keyframes_en_m, c.moves, c.deleted, edited);
      expect(got.accepted.map((m) => m.index)).toEqual(c.expected.accepted);
      expect(pick(got.refusals)).toEqual(pick(c.expected.refusals));
      expect(pick(got.flags)).toEqual(pick(c.expected.flags));
    });
  }
});
