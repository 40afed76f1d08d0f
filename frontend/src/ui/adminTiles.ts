/** Admin: list registered tile sources and add one (a tile file on the server, or an XYZ URL). */
import type { Schemas } from "../api/client";
import { api } from "../api/endpoints";
import { describeError } from "../api/errors";
import type { AppContext } from "./context";
import { h } from "./dom";

export function renderAdminTiles(main: HTMLElement, _ctx: AppContext): void {
  const list = h("div");
  const field = (id: string, label: string, input: HTMLElement) => [h("label", { for: id }, label), input];
  // The escaped "-" keeps the pattern valid under the v flag Chromium compiles it with.
  const name = h("input", { id: "ts-name", required: true, pattern: "[a-z][a-z0-9_\\-]{0,63}", title: "lower-case letters, digits, - and _" });
  const title = h("input", { id: "ts-title" });
  const kind = h("select", { id: "ts-kind" }, ...["street", "satellite", "topo", "other"].map((k) => h("option", { value: k }, k)));
  const origin = h("select", { id: "ts-origin" }, h("option", { value: "path" }, "Tile file on the server (.mbtiles / .pmtiles)"), h("option", { value: "url" }, "Upstream XYZ URL"));
  const location_ = h("input", { id: "ts-location", required: true, placeholder: "basemap/helsinki.pmtiles or https://…/{z}/{x}/{y}.png" });
  const attribution = h("input", { id: "ts-attribution" });
  const msg = h("p", { role: "status", "aria-live": "polite" });
  const form = h("form", { class: "card", "aria-label": "Add a tile source" },
    h("h2", {}, "Add a tile source"),
    ...field("ts-name", "Name (in tile URLs)", name),
    ...field("ts-title", "Title", title),
    ...field("ts-kind", "Kind", kind),
    ...field("ts-origin", "Origin", origin),
    ...field("ts-location", "File path or URL template", location_),
    ...field("ts-attribution", "Attribution", attribution),
    h("button", { type: "submit", class: "primary" }, "Add"),
    msg,
  );
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    const body: Schemas["TileSourceCreate"] = { name: name.value, kind: kind.value as Schemas["TileSourceCreate"]["kind"], attribution: attribution.value, tile_size: 256 };
    if (title.value) body.title = title.value;
    if (origin.value === "url") body.url = location_.value;
    else body.path = location_.value;
    try {
      const ts = await api.addTileSource(body);
      msg.textContent = `Added ${ts.name}.`;
      form.reset();
      load();
    } catch (err) {
      msg.textContent = `Could not add: ${describeError(err)}`;
    }
  });
  function load() {
    api.listTileSources().then(
      (r) =>
        list.replaceChildren(
          r.items.length === 0
            ? h("p", { class: "muted" }, "No tile sources yet.")
            : h("table", { class: "table", "data-testid": "tiles-table" },
                h("thead", {}, h("tr", {}, ...["Name", "Kind", "Zooms", "Format", "Origin", "Attribution", ""].map((t) => h("th", {}, t)))),
                h("tbody", {}, ...r.items.map((t) =>
                  h("tr", {},
                    h("td", {}, t.title || t.name), h("td", {}, t.kind), h("td", {}, `${t.min_zoom}–${t.max_zoom}`), h("td", {}, t.format), h("td", {}, t.origin),
                    h("td", {}, t.attribution),
                    h("td", {}, h("button", {
                      type: "button",
                      "aria-label": `Remove tile source ${t.name}`,
                      onclick: async () => {
                        if (!confirm(`Remove tile source ${t.name}?`)) return;
                        try {
                          await api.deleteTileSource(t.name);
                          load();
                        } catch (err) {
                          msg.textContent = describeError(err);
                        }
                      },
                    }, "Remove")),
                  ),
                )),
              ),
        ),
      (err) => list.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
    );
  }
  main.append(h("section", { class: "page" }, h("h1", {}, "Tile sources"), h("section", { class: "card" }, list), form));
  load();
}
