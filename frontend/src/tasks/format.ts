/** Pure helpers of the task pages (tested without a DOM). */
import { BUILTIN_QUALIFICATIONS, COMPARATOR_WORDS } from "./taskForm";

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

/** A task requirement in words: "approved assignments (count) at least 5". */
export function requirementText(r: { qualification?: unknown; comparator?: unknown; value?: unknown }): string {
  const name = String(r.qualification);
  const v = Array.isArray(r.value) ? r.value.join(", ") : r.value ?? "";
  return `${BUILTIN_QUALIFICATIONS[name] ?? name} ${COMPARATOR_WORDS[String(r.comparator)] ?? String(r.comparator)} ${v}`.trim();
}

export type ReviewCommand = "next" | "previous" | "approve" | "reject" | "solo" | "next-run";

/** The review queue's keys (the `?` overlay lists this table; a unit test checks it against `reviewCommand`). */
export const REVIEW_SHORTCUTS: { keys: string[]; command: ReviewCommand; what: string }[] = [
  { keys: ["J", "ArrowDown"], command: "next", what: "Focus the next submission" },
  { keys: ["K", "ArrowUp"], command: "previous", what: "Focus the previous submission" },
  { keys: ["A"], command: "approve", what: "Approve the focused submission" },
  { keys: ["R"], command: "reject", what: "Reject it: type the reason, then Enter" },
  { keys: ["S"], command: "solo", what: "Show the focused submission alone on the map, or all" },
  { keys: ["N"], command: "next-run", what: "Next run in the review queue" },
];

/** Which review command a key press means, or null. */
export function reviewCommand(e: { key: string; ctrlKey: boolean; metaKey: boolean; altKey?: boolean }): ReviewCommand | null {
  if (e.ctrlKey || e.metaKey || e.altKey) return null;
  if (e.key === "ArrowDown") return "next";
  if (e.key === "ArrowUp") return "previous";
  const k = e.key.toLowerCase();
  return ({ j: "next", k: "previous", a: "approve", r: "reject", s: "solo", n: "next-run" } as Record<string, ReviewCommand>)[k] ?? null;
}
