import { enuProjector } from "../src/rules/geodesy";
import type { EditRules, Keyframe, LonLat, RunDoc } from "../src/state/types";

export const RULES: EditRules = { every_n: 2, lock_n: 2, lock_direction: "forward", max_move_m: 30, order_rule: "refuse", deleted: "remove" };

/** A straight eastward run in Helsinki: keyframe k at k*10 m east of the origin. */
export function straightDoc(n = 20, rules: EditRules = RULES): RunDoc {
  const origin: LonLat = [24.94, 60.17];
  const keyframes: Keyframe[] = [];
  for (let k = 0; k < n; k++) {
    const p = eastOf(origin, k * 10);
    keyframes.push({ index: k, t_s: k, lonlat: p, reported: p, heading_deg: 90, adjustable: k % rules.every_n === 0, locked: false, edited: false, deleted: false, flagged: false, images: k === 0 ? ["1", "2"] : [], correction_m: 0, sigma_m: null });
  }
  return { runId: "1", name: "test", revision: 1, rules, keyframes, drift: null, baseMoves: new Map() };
}

/** The point `east_m` east and `north_m` north of `origin` (inverting the ENU projector numerically). */
export function eastOf(origin: LonLat, east_m: number, north_m = 0): LonLat {
  const proj = enuProjector(origin);
  let p: [number, number] = [origin[0] + east_m / 55600, origin[1] + north_m / 111300];
  for (let it = 0; it < 5; it++) {
    const [e, n] = proj(p);
    p = [p[0] + (east_m - e) / 55600, p[1] + (north_m - n) / 111300];
  }
  return p;
}
