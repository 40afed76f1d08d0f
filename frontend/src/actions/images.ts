/**
 * The run's images as one sequence in keyframe order (every camera of a keyframe in turn):
 * what the image viewer steps through and its filmstrip shows. Pure functions.
 */
import type { RunDoc } from "../state/types";

export interface RunImage {
  /** Image id (the API's). */
  id: string;
  /** Keyframe the image belongs to. */
  keyframe: number;
  /** Camera slot within that keyframe (0-based) and how many it has. */
  camera: number;
  cameras: number;
}

export function imageSequence(doc: RunDoc): RunImage[] {
  const out: RunImage[] = [];
  for (const k of doc.keyframes) k.images.forEach((id, j) => out.push({ id, keyframe: k.index, camera: j, cameras: k.images.length }));
  return out;
}

/** Position of a keyframe's camera image in the sequence; the nearest image at or after the keyframe if it has none. */
export function imageAt(seq: readonly RunImage[], keyframe: number, camera = 0): number {
  const exact = seq.findIndex((x) => x.keyframe === keyframe && x.camera === camera);
  if (exact >= 0) return exact;
  const after = seq.findIndex((x) => x.keyframe >= keyframe);
  return after >= 0 ? after : seq.length - 1;
}

/** Step `d` images from `at`, stopping at the ends of the run. */
export function stepImage(seq: readonly RunImage[], at: number, d: number): number {
  return seq.length === 0 ? -1 : Math.max(0, Math.min(seq.length - 1, at + d));
}

/** Step to the first image of the next (`d` = +1) or previous (-1) keyframe that has images. */
export function stepKeyframe(seq: readonly RunImage[], at: number, d: 1 | -1): number {
  const k = seq[at]?.keyframe;
  if (k === undefined) return at;
  if (d > 0) {
    const i = seq.findIndex((x) => x.keyframe > k);
    return i >= 0 ? i : at;
  }
  let i = at;
  while (i > 0 && seq[i].keyframe === k) i--;
  if (seq[i].keyframe === k) return at;
  const prevK = seq[i].keyframe;
  while (i > 0 && seq[i - 1].keyframe === prevK) i--;
  return i;
}

/** The [start, end) slice of `n` filmstrip frames around `at`, kept inside the sequence. */
export function filmstripWindow(length: number, at: number, n: number): [number, number] {
  if (length <= n) return [0, length];
  const start = Math.max(0, Math.min(length - n, at - Math.floor(n / 2)));
  return [start, start + n];
}
