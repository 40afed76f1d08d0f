/**
 * The rules applied to the editor's data: lon/lat keyframes projected to the run's local
 * east/north plane, the unsaved edits as one batch, earlier revisions' edits as `edited_before`.
 */
import type { Edits, LonLat, Refusal, RunDoc } from "../state/types";
import { enuProjector } from "./geodesy";
import { type EnM, type KeyframeMove, type RuleCheck, checkEdits } from "./rules";

/** Projection of a doc (cached per doc: projecting 10,000 keyframes is done once). */
const cache = new WeakMap<RunDoc, { project: (p: LonLat) => [number, number]; reported: EnM[]; editedBefore: Map<number, EnM> }>();

function prepared(doc: RunDoc) {
  let c = cache.get(doc);
  if (!c) {
    const origin = doc.keyframes[0]?.reported ?? ([0, 0] as LonLat);
    const project = enuProjector(origin);
    const reported = doc.keyframes.map((k) => project(k.reported) as EnM);
    const editedBefore = new Map<number, EnM>();
    for (const k of doc.keyframes) if (k.edited) editedBefore.set(k.index, project(doc.baseMoves.get(k.index) ?? k.lonlat));
    c = { project, reported, editedBefore };
    cache.set(doc, c);
  }
  return c;
}

/** Check the whole batch `edits` against the rules of `doc`. */
export function checkBatch(doc: RunDoc, edits: Edits): RuleCheck {
  const { project, reported, editedBefore } = prepared(doc);
  const moves: KeyframeMove[] = [...edits.moves].map(([index, p]) => {
    const [e, n] = project(p);
    return { index, east_m: e, north_m: n };
  });
  const deleted = new Set(edits.deleted);
  for (const k of doc.keyframes) if (k.deleted) deleted.add(k.index);
  return checkEdits(doc.rules, reported, moves, deleted, editedBefore);
}

/**
 * Check that adding (or replacing) the move of `index` keeps the batch acceptable.
 * Returns the refusal to show, or null. If the new move makes an earlier move fail (it locks
 * it, or reverses order with it), that refusal is returned, worded from the new move.
 */
export function checkNewMove(doc: RunDoc, edits: Edits, index: number, lonlat: LonLat): Refusal | null {
  const moves = new Map(edits.moves);
  moves.set(index, lonlat);
  const result = checkBatch(doc, { ...edits, moves });
  const own = result.refusals.find((r) => r.index === index);
  if (own) return own;
  const other = result.refusals[0];
  if (other) {
    return { index, reason: other.reason, message: `Moving keyframe ${index} would break an earlier move: ${other.message}` };
  }
  return null;
}

/** Flags (accepted but questionable moves, e.g. order under the "flag" rule) for `edits`. */
export function batchFlags(doc: RunDoc, edits: Edits): Refusal[] {
  return checkBatch(doc, edits).flags;
}
