import { describe, expect, it } from "vitest";
import type { StyleSpecification } from "maplibre-gl";
import { mapErrorMessage, zoomNote } from "../src/ui/editor/basemap";

const style = {
  version: 8,
  sources: { toner: { type: "raster", tiles: ["x"], minzoom: 0, maxzoom: 3 }, streets: { type: "vector", tiles: ["y"], minzoom: 12, maxzoom: 15 } },
  layers: [],
} as unknown as StyleSpecification;
const toner = { source: "toner", label: "Toner", kind: "topo", layers: [] };
const streets = { source: "streets", label: "Streets", kind: "street", layers: [] };

describe("basemap messages", () => {
  it("says when the source has no tiles at this zoom", () => {
    expect(zoomNote(style, toner, 2.5)).toBeNull();
    expect(zoomNote(style, toner, 15.2)).toBe("Toner has no tiles beyond zoom 3: what you see is zoom 3 enlarged.");
    expect(zoomNote(style, streets, 9)).toBe("Streets has no tiles below zoom 12: zoom in to see it.");
  });

  it("turns tile fetch failures into 'imagery unavailable'", () => {
    const raw = "AJAXError: Bad Gateway (502): http://127.0.0.1:8000/api/v1/tiles/up/3/4/2.png";
    const said = mapErrorMessage(raw, "Aerial");
    expect(said.startsWith("Imagery unavailable for Aerial")).toBe(true);
    expect(said).not.toContain("http");
    expect(mapErrorMessage("style is not done loading", null)).toBe("Map: style is not done loading");
  });
});
