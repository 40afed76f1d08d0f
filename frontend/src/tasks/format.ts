/** Pure helpers of the task pages (tested without a DOM). */

/** "mm:ss" (or "h:mm:ss") left on a lease; "expired" at or below zero. */
export function fmtRemaining(seconds: number): string {
  if (!(seconds > 0)) return "expired";
  const s = Math.floor(seconds);
  const hh = Math.floor(s / 3600);
  const mm = Math.floor((s % 3600) / 60);
  const ss = s % 60;
  const two = (n: number) => String(n).padStart(2, "0");
  return hh > 0 ? `${hh}:${two(mm)}:${two(ss)}` : `${two(mm)}:${two(ss)}`;
}

/** Seconds left on a lease, measured on the browser clock from the server's remaining time. */
export function remainingAt(remainingAtLoadS: number, loadedAtMs: number, nowMs: number): number {
  return remainingAtLoadS - (nowMs - loadedAtMs) / 1000;
}

/** Warn the operator in the last fifth of the lease (at least the last minute). */
export function leaseUrgent(remainingS: number, leaseS: number): boolean {
  return remainingS <= Math.max(60, leaseS / 5);
}

/** Distinct colours for operators' tracks (colour-blind friendly, Okabe-Ito). */
export const TRACK_COLOURS = ["#E69F00", "#0072B2", "#009E73", "#CC79A7", "#D55E00", "#56B4E9", "#F0E442"];

export function trackColour(i: number): string {
  return TRACK_COLOURS[i % TRACK_COLOURS.length];
}

/** Money from cents with its currency, e.g. "0.50 EUR". */
export function fmtReward(cents: number, currency: string): string {
  return `${(cents / 100).toFixed(2)} ${currency}`;
}

/** The keyframes where operators disagree most, largest first: [index, metres]. */
export function worstKeyframes(disagreementM: number[], n: number, minM = 0): [number, number][] {
  return disagreementM
    .map((d, i) => [i, d] as [number, number])
    .filter(([, d]) => d > minM)
    .sort((a, b) => b[1] - a[1] || a[0] - b[0])
    .slice(0, n);
}

/** A task requirement in words: "approved_count at least 5". */
export function requirementText(r: { qualification?: unknown; comparator?: unknown; value?: unknown }): string {
  const words: Record<string, string> = {
    lt: "less than", le: "at most", gt: "more than", ge: "at least", eq: "exactly", ne: "not",
    exists: "held", not_exists: "not held", in: "one of", not_in: "none of", contains: "contains the run", passed: "passed",
  };
  const v = Array.isArray(r.value) ? r.value.join(", ") : r.value ?? "";
  return `${String(r.qualification)} ${words[String(r.comparator)] ?? String(r.comparator)} ${v}`.trim();
}
