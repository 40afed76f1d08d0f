/**
 * The engine's edit rules, checked against the same vectors pytest reads
 * (tests/vectors/edit_rules.json), so the browser refuses exactly what the server refuses.
 */
import { readFileSync } from "node:fs";
import { resolve } from "node:path";
import { describe, expect, it } from "vitest";
import { type EnM, type KeyframeMove, checkEdits, lockedMask, rulesFromJson } from "../src/rules/rules";

const path = resolve(__dirname, "../../tests/vectors/edit_rules.json");
const vectors = JSON.parse(readFileSync(path, "utf8"));
const cases: Record<string, unknown>[] = Array.isArray(vectors) ? vectors : vectors.cases;

describe("edit rules vectors", () => {
  it("has cases", () => {
    expect(cases.length).toBeGreaterThan(5);
  });
  for (const c of cases) {
    it(String(c.name ?? c.id ?? JSON.stringify(c).slice(0, 60)), () => {
      const rules = rulesFromJson(c.rules as never);
      const reported = (c.reported_en_m ?? c.reported) as EnM[];
      const moves = ((c.moves ?? []) as ({ index: number; east_m: number; north_m: number } | [number, number, number])[]).map(
        (m): KeyframeMove => (Array.isArray(m) ? { index: m[0], east_m: m[1], north_m: m[2] } : m),
      );
      const editedRaw = (c.edited_before ?? {}) as Record<string, [number, number]> | [number, number, number][];
      const edited = new Map<number, EnM>(
        Array.isArray(editedRaw) ? editedRaw.map((e) => [e[0], [e[1], e[2]]]) : Object.entries(editedRaw).map(([k, v]) => [Number(k), v]),
      );
      const got = checkEdits(rules, reported, moves, (c.deleted ?? []) as number[], edited);
      const exp = (c.expected ?? c.expect) as Record<string, unknown>;
      const pick = (rs: { index: number; reason: string }[]) => rs.map((r) => ({ index: r.index, reason: r.reason }));
      if (exp.refusals !== undefined) expect(pick(got.refusals)).toEqual(pick(exp.refusals as never));
      if (exp.flags !== undefined) expect(pick(got.flags)).toEqual(pick(exp.flags as never));
      if (exp.accepted !== undefined) {
        const acc = (exp.accepted as (number | { index: number })[]).map((a) => (typeof a === "number" ? a : a.index));
        expect(got.accepted.map((m) => m.index)).toEqual(acc);
      }
      if (exp.locked !== undefined) {
        const n = reported.length;
        const mask = lockedMask(n, edited.keys(), rules);
        expect(mask.map((b, i) => (b ? i : -1)).filter((i) => i >= 0)).toEqual(exp.locked);
      }
      if (exp.messages !== undefined) expect(got.refusals.map((r) => r.message)).toEqual(exp.messages);
    });
  }
});
