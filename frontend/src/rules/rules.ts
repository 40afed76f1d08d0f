/**
 * The engine's edit rules, ported line for line from `backend/posefix/core/rules.py` so the
 * browser refuses exactly what the server refuses; both are checked against
 * tests/vectors/edit_rules.json.
 *
 * Positions are planar keyframe positions in metres, `[east_m, north_m]` in a local frame
 * (the caller projects lon/lat first, see `projectEnM`). Indices are keyframe indices.
 *
 * Rules, applied in this order to the moves sorted by keyframe index:
 * 1. out_of_range   the index names no keyframe;
 * 2. duplicate      the same keyframe is moved twice in one batch;
 * 3. deleted        the keyframe is deleted in this batch;
 * 4. not_adjustable only every `every_n`-th keyframe (index % every_n == 0) is adjustable;
 * 5. locked         within `lock_n` keyframes after ("forward") or on either side of ("both")
 *                   an earlier-edited keyframe or an accepted move of this batch with a
 *                   lower index;
 * 6. too_far        the move is longer than `max_move_m` (always finite: see core/rules.py);
 * 7. order_reversed between two consecutive surviving keyframes i < j, each where it now
 *                   lies (moved in this batch or an earlier edit, else where it was reported),
 *                   the chord c_j - c_i points backwards along the reported chord (dot <= 0;
 *                   chords shorter than 1 m are not judged): a pose dragged past an unmoved
 *                   neighbour reverses the order too. Only pairs with a move of this batch
 *                   are judged; its move is the culprit (the later one when both are).
 *                   "refuse" refuses it, "flag" accepts it with a flag.
 * Rules 1-6 always refuse. A refused move is left out before rule 7 is judged.
 */
import type { EditRules, Refusal } from "../state/types";

export const REASONS = [
  "out_of_range",
  "duplicate",
  "deleted",
  "not_adjustable",
  "locked",
  "too_far",
  "order_reversed",
] as const;

export const MIN_CHORD_M = 1.0;

export type EnM = readonly [number, number];

/** Move keyframe `index` to (east_m, north_m) in the local frame. */
export interface KeyframeMove {
  index: number;
  east_m: number;
  north_m: number;
}

export interface RuleCheck {
  accepted: KeyframeMove[];
  refusals: Refusal[];
  flags: Refusal[];
}

export const DEFAULT_RULES: EditRules = {
  every_n: 1,
  lock_n: 0,
  lock_direction: "forward",
  max_move_m: 1000,
  order_rule: "flag",
  deleted: "remove",
};

/** Rules from the server's JSON, defaults for missing keys (as `EditRules.from_json`). */
export function rulesFromJson(data: Partial<EditRules> | null | undefined): EditRules {
  return { ...DEFAULT_RULES, ...(data ?? {}) };
}

/** Whether keyframe `index` is one an operator may move at all. */
export function isAdjustable(index: number, rules: EditRules): boolean {
  return index % Math.max(Math.trunc(rules.every_n), 1) === 0;
}

/** Keyframe indices locked by an edit at `index` (the edited one excluded). */
export function lockSpan(index: number, nKeyframes: number, rules: EditRules): number[] {
  const hi = Math.min(index + rules.lock_n, nKeyframes - 1);
  const lo = rules.lock_direction === "both" ? Math.max(index - rules.lock_n, 0) : index + 1;
  const out: number[] = [];
  for (let j = lo; j <= hi; j++) out.push(j);
  return out;
}

/** Keyframes locked by the edited keyframes (which are never locked themselves). */
export function lockedMask(nKeyframes: number, edited: Iterable<number>, rules: EditRules): boolean[] {
  const locked = new Array<boolean>(nKeyframes).fill(false);
  const ed = [...edited];
  for (const i of ed) for (const j of lockSpan(i, nKeyframes, rules)) locked[j] = true;
  for (const i of ed) if (i >= 0 && i < nKeyframes) locked[i] = false;
  return locked;
}

/** Apply the rules to one batch of moves (see the module comment). */
export function checkEdits(
  rules: EditRules,
  reportedEnM: readonly EnM[],
  moves: readonly KeyframeMove[],
  deleted: Iterable<number> = [],
  editedBefore: ReadonlyMap<number, EnM> = new Map(),
): RuleCheck {
  const k = reportedEnM.length;
  const deletedSet = new Set(deleted);
  const refusals: Refusal[] = [];
  const flags: Refusal[] = [];
  const seen = new Set<number>();
  let accepted: KeyframeMove[] = [];
  const movedIdx = new Set(moves.map((m) => m.index));
  const lockSources = [...editedBefore.keys()].filter((i) => !movedIdx.has(i)).sort((a, b) => a - b);
  const locked = new Set<number>();
  for (const i of lockSources) for (const j of lockSpan(i, k, rules)) locked.add(j);
  // Stable sort by index, as Python's sorted().
  const sorted = moves.map((m, n) => [m, n] as const).sort((a, b) => a[0].index - b[0].index || a[1] - b[1]).map((x) => x[0]);
  for (const move of sorted) {
    const i = Math.trunc(move.index);
    const refusal = firstRefusal(rules, reportedEnM, move, k, seen, deletedSet, locked);
    seen.add(i);
    if (refusal) {
      refusals.push(refusal);
      continue;
    }
    accepted.push(move);
    for (const j of lockSpan(i, k, rules)) if (j !== i) locked.add(j);
  }
  const reversed = orderReversals(rules, reportedEnM, accepted, deletedSet, editedBefore, refusals, flags);
  if (rules.order_rule === "refuse") accepted = accepted.filter((m) => !reversed.has(m.index));
  return { accepted, refusals, flags };
}

/** Rule 7 over every surviving keyframe in track order; pushes to `refusals` or `flags`, returns the culprits. */
function orderReversals(
  rules: EditRules,
  reported: readonly EnM[],
  accepted: readonly KeyframeMove[],
  deletedSet: Set<number>,
  editedBefore: ReadonlyMap<number, EnM>,
  refusals: Refusal[],
  flags: Refusal[],
): Set<number> {
  const k = reported.length;
  const now: EnM[] = reported.slice();
  for (const [i, xy] of editedBefore) if (i >= 0 && i < k) now[i] = xy;
  const batch = new Set(accepted.map((m) => m.index));
  for (const m of accepted) now[m.index] = [m.east_m, m.north_m];
  const culprits = new Set<number>();
  let a = -1;
  for (let b = 0; b < k; b++) {
    if (deletedSet.has(b)) continue;
    if (a >= 0 && (batch.has(a) || batch.has(b))) {
      const chord = [reported[b][0] - reported[a][0], reported[b][1] - reported[a][1]];
      const moved = [now[b][0] - now[a][0], now[b][1] - now[a][1]];
      if (Math.hypot(chord[0], chord[1]) >= MIN_CHORD_M && moved[0] * chord[0] + moved[1] * chord[1] <= 0) {
        const culprit = batch.has(b) ? b : a;
        if (!culprits.has(culprit)) {
          culprits.add(culprit);
          const other = culprit === b ? a : b;
          const item: Refusal = {
            index: culprit,
            reason: "order_reversed",
            message: `Moving keyframe ${culprit} puts it on the wrong side of keyframe ${other}: the poses would run backwards along the track.`,
          };
          (rules.order_rule === "refuse" ? refusals : flags).push(item);
        }
      }
    }
    a = b;
  }
  return culprits;
}

function firstRefusal(
  rules: EditRules,
  reported: readonly EnM[],
  move: KeyframeMove,
  k: number,
  seen: Set<number>,
  deletedSet: Set<number>,
  locked: Set<number>,
): Refusal | null {
  const i = Math.trunc(move.index);
  if (i < 0 || i >= k) {
    return { index: i, reason: "out_of_range", message: `There is no keyframe ${i}; this run has ${k} keyframes (0 to ${k - 1}).` };
  }
  if (seen.has(i)) {
    return { index: i, reason: "duplicate", message: `Keyframe ${i} is moved twice in one batch; send one move per keyframe.` };
  }
  if (deletedSet.has(i)) {
    return { index: i, reason: "deleted", message: `Keyframe ${i} is deleted in this batch and cannot also be moved.` };
  }
  if (!isAdjustable(i, rules)) {
    return { index: i, reason: "not_adjustable", message: `Only every ${ordinal(rules.every_n)} keyframe can be moved; keyframe ${i} is not one of them.` };
  }
  if (locked.has(i)) {
    return { index: i, reason: "locked", message: `Keyframe ${i} is locked: it lies within ${rules.lock_n} keyframe${rules.lock_n === 1 ? "" : "s"} of an edited keyframe.` };
  }
  const distanceM = Math.hypot(move.east_m - reported[i][0], move.north_m - reported[i][1]);
  if (distanceM > rules.max_move_m) {
    return { index: i, reason: "too_far", message: `Keyframe ${i} would move ${distanceM.toFixed(1)} m; the limit is ${formatG(rules.max_move_m)} m.` };
  }
  return null;
}

/** 1st, 2nd, 3rd, 4th, 11th, 12th, 21st… */
export function ordinal(n: number): string {
  const teen = Math.abs(n) % 100 >= 11 && Math.abs(n) % 100 <= 13;
  const suffix = teen ? "th" : ({ 1: "st", 2: "nd", 3: "rd" } as Record<number, string>)[Math.abs(n) % 10] ?? "th";
  return `${n}${suffix}`;
}

/** Python's `:g` for the limits we print (no trailing zeros). */
export function formatG(x: number): string {
  return String(Number(x.toPrecision(6)));
}
