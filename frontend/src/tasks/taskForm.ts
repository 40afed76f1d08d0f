/**
 * Pure helpers of the task form (tested without a DOM): which qualifications and comparators
 * may be picked (mirroring the server's `validate_requirement`), in words, and where the run
 * map should look.
 */

export type Box = readonly [number, number, number, number];

/** The built-in qualifications, in words. Other names are those admins have granted. */
export const BUILTIN_QUALIFICATIONS: Record<string, string> = {
  approved_count: "approved assignments (count)",
  accuracy_m: "accuracy on gold runs (m)",
  home_area: "home area",
  qualification_test: "qualification test",
};

export const COMPARATOR_WORDS: Record<string, string> = {
  ge: "at least", gt: "more than", le: "at most", lt: "less than", eq: "exactly", ne: "other than",
  exists: "is held", not_exists: "is not held", in: "is one of", not_in: "is none of", contains: "contains the run", passed: "passed",
};

const NUMERIC = ["ge", "gt", "le", "lt", "eq", "ne"];

/** The comparators the server accepts for qualification `name`. */
export function comparatorsFor(name: string): string[] {
  if (name === "home_area") return ["contains"];
  if (name === "qualification_test") return ["passed"];
  if (name === "approved_count" || name === "accuracy_m") return NUMERIC;
  return [...NUMERIC, "exists", "not_exists", "in", "not_in"];
}

/** Whether comparator `c` takes a value (a number, or a list of numbers). */
export function takesValue(c: string): "number" | "list" | null {
  if (NUMERIC.includes(c)) return "number";
  return c === "in" || c === "not_in" ? "list" : null;
}

/** Every qualification name to pick from: the built-in ones, then the granted ones (sorted, once each). */
export function qualificationNames(operators: readonly { qualifications?: readonly { name: string }[] }[]): string[] {
  const granted = new Set<string>();
  for (const o of operators) for (const q of o.qualifications ?? []) if (!(q.name in BUILTIN_QUALIFICATIONS)) granted.add(q.name);
  return [...Object.keys(BUILTIN_QUALIFICATIONS), ...[...granted].sort()];
}

/** The requirement's value as the API wants it, or an error in words. */
export function requirementValue(comparator: string, raw: string): { value: number | number[] | null } | { error: string } {
  const kind = takesValue(comparator);
  const t = raw.trim();
  if (kind === null) return { value: null };
  if (kind === "number") {
    const v = Number(t);
    return t !== "" && Number.isFinite(v) ? { value: v } : { error: `“${COMPARATOR_WORDS[comparator]}” needs a number` };
  }
  const vs = t.split(",").map((x) => Number(x.trim()));
  return t !== "" && vs.every(Number.isFinite) ? { value: vs } : { error: `“${COMPARATOR_WORDS[comparator]}” needs numbers separated by commas` };
}

function union(boxes: readonly Box[]): Box | null {
  if (boxes.length === 0) return null;
  return [Math.min(...boxes.map((b) => b[0])), Math.min(...boxes.map((b) => b[1])), Math.max(...boxes.map((b) => b[2])), Math.max(...boxes.map((b) => b[3]))];
}

function centre(b: Box): [number, number] {
  return [(b[0] + b[2]) / 2, (b[1] + b[3]) / 2];
}

/** Great-circle distance (km) between two [lon, lat] points: enough to group runs by region. */
function km(a: [number, number], b: [number, number]): number {
  const r = Math.PI / 180;
  const s = Math.sin(((b[1] - a[1]) * r) / 2) ** 2 + Math.cos(a[1] * r) * Math.cos(b[1] * r) * Math.sin(((b[0] - a[0]) * r) / 2) ** 2;
  return 2 * 6371 * Math.asin(Math.min(1, Math.sqrt(s)));
}

export interface MapRun {
  id: number;
  bbox: readonly number[];
  created_at: string;
}

export type MapFocus = { kind: "box"; box: Box } | { kind: "view"; center: [number, number]; zoom: number } | null;

/**
 * Where the run map looks: the selected runs; else the view the admin last left it at; else
 * the region of the newest run (runs within `regionKm` of it). Never every run in the world.
 */
export function runMapFocus(runs: readonly MapRun[], selected: ReadonlySet<number>, saved: { center: [number, number]; zoom: number } | null, regionKm = 50): MapFocus {
  const valid = runs.filter((r) => r.bbox.length === 4 && r.bbox.every(Number.isFinite)).map((r) => ({ ...r, box: r.bbox as unknown as Box }));
  const sel = union(valid.filter((r) => selected.has(r.id)).map((r) => r.box));
  if (sel) return { kind: "box", box: sel };
  if (saved && saved.center.every(Number.isFinite) && Number.isFinite(saved.zoom)) return { kind: "view", ...saved };
  if (valid.length === 0) return null;
  const newest = valid.reduce((a, b) => (b.created_at > a.created_at || (b.created_at === a.created_at && b.id > a.id) ? b : a));
  const c = centre(newest.box);
  const box = union(valid.filter((r) => km(centre(r.box), c) <= regionKm).map((r) => r.box));
  return box ? { kind: "box", box } : null;
}

/**
 * The run a click at [lon, lat] means: the smallest outline containing it, within `tol`
 * degrees ([lon, lat]) of its edges so a click on an outline counts; among equal outlines the
 * newest (highest id). Nested outlines stay pickable.
 */
export function runAt(runs: readonly { id: number; bbox: readonly number[] }[], lon: number, lat: number, tol: readonly [number, number] = [0, 0]): number | null {
  let best: { id: number; area: number } | null = null;
  for (const r of runs) {
    const [a, b, c, d] = r.bbox;
    if (lon < a - tol[0] || lon > c + tol[0] || lat < b - tol[1] || lat > d + tol[1]) continue;
    const area = (c - a) * (d - b);
    if (!best || area < best.area || (area === best.area && r.id > best.id)) best = { id: r.id, area };
  }
  return best?.id ?? null;
}
