/** Operator home: the runs they may edit. Tasks (assignments) will be listed here too. */
import { api } from "../api/endpoints";
import { describeError } from "../api/errors";
import type { AppContext } from "./context";
import { fmtTime, h } from "./dom";

export function renderHome(main: HTMLElement, ctx: AppContext): void {
  const list = h("div", { "aria-live": "polite" }, h("p", {}, "Loading runs…"));
  main.append(
    h("section", { class: "page" },
      h("h1", {}, `Welcome, ${ctx.user?.username ?? ""}`),
      h("section", { class: "card", "aria-labelledby": "tasks-h" },
        h("h2", { id: "tasks-h" }, "My tasks"),
        h("p", {}, h("a", { href: "#/tasks/work", "data-testid": "home-work" }, "Get your next task"), " — your assignments and statistics are on the Work page."),
      ),
      h("section", { class: "card", "aria-labelledby": "runs-h" }, h("h2", { id: "runs-h" }, "Runs you may edit"), list),
    ),
  );
  api.listRuns({ limit: 200 }).then(
    (r) => {
      list.replaceChildren(
        r.items.length === 0
          ? h("p", { class: "muted" }, "No runs to edit yet.")
          : h("table", { class: "table", "data-testid": "runs-table" },
              h("thead", {}, h("tr", {}, h("th", {}, "Run"), h("th", {}, "Status"), h("th", {}, "Revision"), h("th", {}, "Updated"))),
              h("tbody", {}, ...r.items.map((run) =>
                h("tr", {},
                  h("td", {}, h("a", { href: `#/runs/${encodeURIComponent(String(run.id))}` }, run.name)),
                  h("td", {}, h("span", { class: `status status-${run.status}` }, String(run.status ?? ""))),
                  h("td", {}, String(run.revision)),
                  h("td", {}, fmtTime(run.updated_at)),
                ),
              )),
            ),
      );
    },
    (err) => list.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
  );
}
