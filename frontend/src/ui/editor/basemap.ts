/**
 * The basemap: the server's MapLibre style (all configured tile sources), and a switcher
 * that shows one source at a time by toggling the visibility of the layers drawing it.
 * Attribution comes from each source's `attribution` (MapLibre's attribution control).
 */
import type { Map as MlMap, StyleSpecification } from "maplibre-gl";
import { h } from "../dom";

export interface BasemapOption {
  source: string;
  label: string;
  kind: string;
  layers: string[];
}

/**
 * Basemap options from the style. The server lists them in `metadata["posefix:sources"]`
 * (name, title, kind, layer ids, in switcher order); a style without it falls back to one
 * option per source found in the layers.
 */
export function basemapOptions(style: StyleSpecification): BasemapOption[] {
  const meta = (style.metadata ?? {}) as Record<string, unknown>;
  const listed = meta["posefix:sources"];
  if (Array.isArray(listed)) {
    return listed.map((m: { name: string; title?: string; kind?: string; layers?: string[] }) => ({
      source: m.name,
      label: m.title || m.name,
      kind: m.kind ?? "other",
      layers: m.layers ?? style.layers.filter((l) => (l as { source?: string }).source === m.name).map((l) => l.id),
    }));
  }
  const bySource = new Map<string, string[]>();
  for (const l of style.layers) {
    const src = (l as { source?: string }).source;
    if (!src || src.startsWith("pf-")) continue;
    if (!bySource.has(src)) bySource.set(src, []);
    bySource.get(src)!.push(l.id);
  }
  return [...bySource].map(([source, layers]) => ({ source, layers, kind: "other", label: source }));
}

/** Show only `source`'s layers. */
export function showBasemap(map: MlMap, opts: BasemapOption[], source: string): void {
  for (const o of opts) {
    for (const id of o.layers) if (map.getLayer(id)) map.setLayoutProperty(id, "visibility", o.source === source ? "visible" : "none");
  }
}

/** The switcher control: one radio per basemap, keyboard reachable, labelled by kind. */
export function basemapSwitcher(opts: BasemapOption[], initial: string | null, onChange: (source: string) => void): HTMLElement {
  const box = h("fieldset", { class: "basemap-switcher" }, h("legend", {}, "Basemap"));
  if (opts.length === 0) box.append(h("p", { class: "muted" }, "none configured"));
  for (const o of opts) {
    const id = `basemap-${o.source}`;
    const input = h("input", { type: "radio", name: "basemap", id, value: o.source, checked: o.source === initial });
    input.addEventListener("change", () => input.checked && onChange(o.source));
    box.append(h("label", { for: id, class: "radio" }, input, ` ${o.label} (${o.kind})`));
  }
  return box;
}

/** The source visible when the style loads (the first with a visible layer). */
export function initialBasemap(style: StyleSpecification, opts: BasemapOption[]): string | null {
  const named = ((style.metadata ?? {}) as Record<string, unknown>)["posefix:default"];
  if (typeof named === "string" && opts.some((o) => o.source === named)) return named;
  for (const o of opts) {
    const visible = o.layers.some((id) => {
      const l = style.layers.find((x) => x.id === id) as { layout?: { visibility?: string } } | undefined;
      return (l?.layout?.visibility ?? "visible") === "visible";
    });
    if (visible) return o.source;
  }
  return opts[0]?.source ?? null;
}

/** What to say when `source` has no tiles at `zoom` (MapLibre enlarges the last level, or shows nothing). */
export function zoomNote(style: StyleSpecification, opt: BasemapOption | undefined, zoom: number): string | null {
  if (!opt) return null;
  const src = style.sources[opt.source] as { minzoom?: number; maxzoom?: number } | undefined;
  if (!src) return null;
  const z = Math.floor(zoom);
  if (src.maxzoom !== undefined && z > src.maxzoom) return `${opt.label} has no tiles beyond zoom ${src.maxzoom}: what you see is zoom ${src.maxzoom} enlarged.`;
  if (src.minzoom !== undefined && z < src.minzoom) return `${opt.label} has no tiles below zoom ${src.minzoom}: zoom in to see it.`;
  return null;
}

/** A map error in words: tile fetch failures become "imagery unavailable", not a raw URL. */
export function mapErrorMessage(raw: string, label: string | null): string {
  if (/AJAXError|Failed to fetch|NetworkError|\b(40[34]|5\d\d)\b/.test(raw)) {
    return `Imagery unavailable${label ? ` for ${label}` : ""}: its tile server could not deliver tiles here. Editing still works; try another basemap.`;
  }
  return `Map: ${raw}`;
}
