/** Admin page: operators, their statistics, qualifications and home areas. */
import { describeError } from "../api/errors";
import type { AppContext } from "../ui/context";
import { h } from "../ui/dom";
import { type OperatorStats, tasksApi } from "./api";

const fmt = (v: number | null, unit = "") => (v === null ? "—" : `${v.toFixed(2)}${unit}`);

export function renderOperators(main: HTMLElement, _ctx: AppContext): void {
  const box = h("div", { "data-testid": "operators" }, h("p", {}, "Loading…"));
  main.append(h("section", { class: "page wide" }, h("h1", {}, "Operators"), h("section", { class: "card" }, box)));

  function row(o: OperatorStats): HTMLElement {
    const name = h("input", { placeholder: "qualification", "aria-label": `Qualification for ${o.username}`, size: 12 });
    const value = h("input", { type: "number", value: "1", "aria-label": "Value", style: { width: "4em" } });
    const msg = h("span", { role: "status" });
    const grant = async () => {
      try {
        await tasksApi.grant(o.user_id, name.value.trim(), Number(value.value));
        void load();
      } catch (err) {
        msg.textContent = describeError(err);
      }
    };
    const home = h("input", { placeholder: "lon, lat, radius m", "aria-label": `Home area of ${o.username}`, size: 18 });
    const setHome = async () => {
      const [lon, lat, radius] = home.value.split(",").map((x) => Number(x.trim()));
      try {
        await tasksApi.setHome(o.user_id, { lon, lat, radius_m: radius });
        void load();
      } catch (err) {
        msg.textContent = describeError(err);
      }
    };
    const ha = o.home_area as { lon?: number; lat?: number; radius_m?: number; polygon?: unknown[] } | null;
    return h("tr", { "data-testid": `operator-${o.username}` },
      h("td", {}, o.username),
      h("td", {}, `${o.submitted} / ${o.approved} / ${o.rejected}`),
      h("td", {}, `${o.returned} / ${o.expired}`),
      h("td", {}, o.gold_scored ? `${fmt(o.accuracy_m, " m")} (${o.gold_scored})` : "—"),
      h("td", {}, fmt(o.agreement_m, " m")),
      h("td", {}, o.throughput_per_h === null ? "—" : `${o.throughput_per_h.toFixed(1)}/h`),
      h("td", {}, o.test_status.replace("_", " ")),
      h("td", {}, ...o.qualifications.map((q) => h("span", { class: "chip" }, `${q.name}=${q.value} `,
        h("button", { type: "button", "aria-label": `Revoke ${q.name}`, onclick: async () => {
          try { await tasksApi.revoke(o.user_id, q.name); void load(); } catch (err) { msg.textContent = describeError(err); }
        } }, "×"))), name, value, h("button", { type: "button", onclick: () => void grant() }, "Grant")),
      h("td", {}, ha ? (ha.polygon ? "polygon" : `${ha.lon?.toFixed(4)}, ${ha.lat?.toFixed(4)} ± ${ha.radius_m} m`) : "—", " ", home,
        h("button", { type: "button", onclick: () => void setHome() }, "Set"), msg),
    );
  }

  async function load() {
    try {
      const ops = await tasksApi.operators();
      box.replaceChildren(h("table", { class: "table" },
        h("thead", {}, h("tr", {}, h("th", {}, "Operator"), h("th", {}, "Submitted / approved / rejected"), h("th", {}, "Returned / expired"),
          h("th", {}, "Accuracy (gold)"), h("th", {}, "To consensus"), h("th", {}, "Throughput"), h("th", {}, "Test"),
          h("th", {}, "Qualifications"), h("th", {}, "Home area"))),
        h("tbody", {}, ...ops.map(row))));
    } catch (err) {
      box.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err)));
    }
  }
  void load();
}
