/**
 * Requester/admin page: create a task (runs chosen from a list and on a map) and monitor
 * tasks: progress by assignment status, each run's state and conflicts (polled).
 */
import type * as maplibregl from "maplibre-gl";
import { describeError } from "../api/errors";
import type { AppContext } from "../ui/context";
import { fmtTime, h, plural } from "../ui/dom";
import { createMap, fitBoxes } from "../map/createMap";
import { type Json, type Task, type TaskCreate, tasksApi } from "./api";
import { fmtReward, requirementText } from "./format";
import { BUILTIN_QUALIFICATIONS, COMPARATOR_WORDS, comparatorsFor, qualificationNames, requirementValue, runAt, runMapFocus, takesValue } from "./taskForm";

const VIEW_KEY = "posefix.taskmap.view";

function savedView(): { center: [number, number]; zoom: number } | null {
  try {
    const v = JSON.parse(localStorage.getItem(VIEW_KEY) ?? "null") as { center: [number, number]; zoom: number } | null;
    return v && Array.isArray(v.center) ? v : null;
  } catch {
    return null;
  }
}

/** One requirement row: the qualification picked from the known names, the comparator in words. */
function requirementRow(names: readonly string[]): HTMLElement {
  const q = h("select", { "aria-label": "Qualification", "data-testid": "req-qualification" },
    ...names.map((n) => h("option", { value: n }, BUILTIN_QUALIFICATIONS[n] ?? n)));
  const c = h("select", { "aria-label": "Comparator", "data-testid": "req-comparator" });
  const v = h("input", { "aria-label": "Value", "data-testid": "req-value" });
  const del = h("button", { type: "button", "aria-label": "Remove requirement" }, "×");
  const row = h("div", { class: "req" }, q, c, v, del);
  const fillComparators = () => {
    c.replaceChildren(...comparatorsFor(q.value).map((x) => h("option", { value: x }, COMPARATOR_WORDS[x] ?? x)));
    fillValue();
  };
  const fillValue = () => {
    const kind = takesValue(c.value);
    v.hidden = kind === null;
    v.placeholder = kind === "list" ? "numbers, e.g. 1, 2, 3" : "a number";
  };
  q.addEventListener("change", fillComparators);
  c.addEventListener("change", fillValue);
  del.addEventListener("click", () => row.remove());
  fillComparators();
  return row;
}

function field(label: string, input: HTMLElement, hint = ""): HTMLElement {
  return h("label", { class: "field" }, h("span", {}, label), input, hint ? h("small", { class: "muted" }, hint) : null);
}

function numberInput(name: string, value: number, attrs: Record<string, unknown> = {}): HTMLInputElement {
  return h("input", { type: "number", name, value: String(value), ...attrs });
}

export function renderTasksAdmin(main: HTMLElement, ctx: AppContext): () => void {
  const cleanups: (() => void)[] = [];
  const selected = new Set<number>();
  const runList = h("div", { class: "run-choice", "data-testid": "run-choice" }, h("p", {}, "Loading runs…"));
  const mapEl = h("div", { class: "choice-map", "aria-label": "Runs on the map: click one to select it" });
  const title = h("input", { name: "title", required: true, value: "Correct the drives", "aria-label": "Title" });
  const instructions = h("textarea", { name: "instructions", rows: 3, "aria-label": "Instructions" }, "Drag keyframes onto the centre of the lane the car drove in.");
  const reward = numberInput("reward", 50, { min: 0, "aria-label": "Reward (cents)" });
  const currency = h("input", { name: "currency", value: "EUR", maxlength: 3, "aria-label": "Currency" });
  const perRun = numberInput("assignments_per_run", 2, { min: 1, max: 50, "aria-label": "Assignments per run" });
  const leaseMin = numberInput("lease_min", 30, { min: 1, "aria-label": "Lease (minutes)" });
  const lifetimeH = numberInput("lifetime_h", 168, { min: 1, "aria-label": "Lifetime (hours)" });
  const autoH = numberInput("auto_h", 72, { min: 0, step: "any", "aria-label": "Auto-approval delay (hours)" });
  const priority = numberInput("priority", 0, { "aria-label": "Priority" });
  const policy = h("select", { name: "policy", "aria-label": "On conflict" },
    h("option", { value: "flag" }, "flag for adjudication"), h("option", { value: "extend" }, "ask one more operator"));
  const distM = numberInput("dist", 5, { min: 0.1, step: "any", "aria-label": "Conflict distance (m)" });
  const distK = numberInput("kf", 3, { min: 1, "aria-label": "Conflict keyframes" });
  const editM = numberInput("edit_m", 5, { min: 0.1, step: "any", "aria-label": "Edit conflict distance (m)" });
  const useRules = h("input", { type: "checkbox", "aria-label": "Set editing rules" });
  const everyN = numberInput("every_n", 1, { min: 1, "aria-label": "Every Nth keyframe adjustable" });
  const lockN = numberInput("lock_n", 0, { min: 0, "aria-label": "Lock N after a move" });
  const lockDir = h("select", { "aria-label": "Lock direction" }, h("option", { value: "forward" }, "forward"), h("option", { value: "both" }, "both"));
  const maxMove = numberInput("max_move", 1000, { min: 1, max: 10000, step: "any", "aria-label": "Maximum move (m, 1 to 10,000)" });
  const orderRule = h("select", { "aria-label": "Order rule" }, h("option", { value: "flag" }, "flag"), h("option", { value: "refuse" }, "refuse"));
  const reqRows = h("div", { class: "reqs" });
  const addReq = h("button", { type: "button" }, "+ requirement");
  let qualNames = qualificationNames([]);
  if (ctx.user?.role === "admin") {
    // Granted names come from the operators; a client sees the built-in ones.
    tasksApi.operators().then((ops) => (qualNames = qualificationNames(ops)), () => undefined);
  }
  addReq.addEventListener("click", () => {
    if (reqRows.children.length >= 10) return;
    reqRows.append(requirementRow(qualNames));
  });
  const formMsg = h("p", { role: "status", "data-testid": "create-msg" });
  const form = h("form", { class: "card task-form", "data-testid": "task-form" },
    h("h2", {}, "New task"),
    field("Title", title), field("Instructions", instructions),
    h("div", { class: "row" }, field("Reward (cents)", reward), field("Currency", currency), field("Assignments per run", perRun),
      field("Priority", priority)),
    h("div", { class: "row" }, field("Lease (minutes)", leaseMin), field("Lifetime (hours)", lifetimeH), field("Auto-approval after (hours)", autoH)),
    h("div", { class: "row" }, field("On conflict", policy), field("Tracks apart by more than (m)", distM), field("over keyframes", distK),
      field("Edits of one keyframe apart by (m)", editM)),
    h("fieldset", {}, h("legend", {}, h("label", {}, useRules, " Editing rules for these runs")),
      h("div", { class: "row" }, field("Every Nth adjustable", everyN), field("Lock N after a move", lockN), field("Lock direction", lockDir),
        field("Max move (m)", maxMove), field("Order", orderRule))),
    h("fieldset", {}, h("legend", {}, "Qualification requirements (up to 10)"), reqRows, addReq),
    h("fieldset", {}, h("legend", {}, "Runs"), h("div", { class: "run-pick" }, runList, mapEl)),
    h("button", { type: "submit", class: "primary", "data-testid": "create-task" }, "Create task"),
    formMsg,
  );
  const tasksBox = h("div", { "data-testid": "tasks-list" }, h("p", {}, "Loading tasks…"));
  main.append(h("section", { class: "page wide" }, h("h1", {}, "Tasks"), form,
    h("section", { class: "card" }, h("h2", {}, "Progress"), tasksBox)));

  let runs: { id: number; name: string; status: string; bbox: number[]; n_keyframes: number; created_at: string }[] = [];
  let map: maplibregl.Map | null = null;
  const boxes: Record<number, HTMLInputElement> = {};
  function renderMapSelection() {
    if (!map || !map.getSource("runs")) return;
    (map.getSource("runs") as maplibregl.GeoJSONSource).setData(runsGeoJSON());
  }
  function runsGeoJSON(): GeoJSON.FeatureCollection {
    return {
      type: "FeatureCollection",
      features: runs.map((r) => {
        const [a, b, c, d] = r.bbox;
        return { type: "Feature", properties: { id: r.id, selected: selected.has(r.id) ? 1 : 0, name: r.name },
          geometry: { type: "Polygon", coordinates: [[[a, b], [c, b], [c, d], [a, d], [a, b]]] } };
      }),
    };
  }
  function toggle(id: number, on: boolean, refit: boolean) {
    if (on) selected.add(id);
    else selected.delete(id);
    if (boxes[id]) boxes[id].checked = on;
    renderMapSelection();
    if (refit && selected.size) focusMap(true);
  }
  /** Look at the selected runs, else where the admin was working (see runMapFocus). */
  function focusMap(animate: boolean) {
    if (!map) return;
    const f = runMapFocus(runs, selected, savedView());
    if (f?.kind === "box") fitBoxes(map, [f.box], { padding: 30, maxZoom: 15, animate });
    else if (f?.kind === "view") map.jumpTo({ center: f.center, zoom: f.zoom });
  }
  tasksApi.runs().then((r) => {
    runs = r.items;
    runList.replaceChildren(runs.length === 0 ? h("p", { class: "muted" }, "No runs yet: upload some first.") :
      h("ul", { class: "plain" }, ...runs.map((run) => {
        const cb = h("input", { type: "checkbox", value: String(run.id), "data-run": String(run.id), "aria-label": `Run ${run.name}` });
        cb.addEventListener("change", () => toggle(run.id, cb.checked, true));
        boxes[run.id] = cb;
        return h("li", {}, h("label", {}, cb, ` ${run.name} `, h("span", { class: "muted" }, `#${run.id} · ${plural(run.n_keyframes, "keyframe")} · ${run.status}`)));
      })));
    void showMap();
  }, (err) => runList.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))));

  async function showMap() {
    if (runs.length === 0) return;
    const made = await createMap(mapEl, { zoom: 11, compactAttribution: true, exposeAs: "__posefixTaskMap", alive: () => alive });
    if (!made) return;
    const m = made.map;
    map = m;
    m.on("load", () => {
      m.addSource("runs", { type: "geojson", data: runsGeoJSON() });
      m.addLayer({ id: "runs-fill", type: "fill", source: "runs",
        paint: { "fill-color": ["case", ["==", ["get", "selected"], 1], "#2563eb", "#94a3b8"], "fill-opacity": 0.25 } });
      m.addLayer({ id: "runs-line", type: "line", source: "runs",
        paint: { "line-color": ["case", ["==", ["get", "selected"], 1], "#1d4ed8", "#475569"], "line-width": 2 } });
      focusMap(false);
      m.on("click", (e) => {
        // 8 px of slack, so a click on a run's outline (or just outside it) picks it too.
        const off = m.unproject([e.point.x + 8, e.point.y + 8]);
        const tol: [number, number] = [Math.abs(off.lng - e.lngLat.lng), Math.abs(off.lat - e.lngLat.lat)];
        const id = runAt(runs, e.lngLat.lng, e.lngLat.lat, tol);
        if (id !== null) toggle(id, !selected.has(id), false);
      });
      m.on("mouseenter", "runs-fill", () => (m.getCanvas().style.cursor = "pointer"));
      m.on("mouseleave", "runs-fill", () => (m.getCanvas().style.cursor = ""));
      m.on("moveend", () => {
        try {
          localStorage.setItem(VIEW_KEY, JSON.stringify({ center: m.getCenter().toArray(), zoom: m.getZoom() }));
        } catch {
          /* storage disabled: the map falls back to the newest run's region */
        }
      });
      mapEl.dataset.ready = "true";
    });
  }
  let alive = true;
  cleanups.push(() => {
    alive = false;
    map?.remove();
  });

  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    formMsg.textContent = "";
    const requirements: Json[] = [];
    for (const row of Array.from(reqRows.children)) {
      const [q, c, v] = Array.from(row.querySelectorAll("input, select")) as HTMLInputElement[];
      const r = requirementValue(c.value, v.value);
      if ("error" in r) {
        formMsg.textContent = `Requirement “${BUILTIN_QUALIFICATIONS[q.value] ?? q.value}”: ${r.error}.`;
        v.focus();
        return;
      }
      requirements.push({ qualification: q.value, comparator: c.value, value: r.value });
    }
    const body: Json = {
      title: title.value, instructions: instructions.value, run_ids: [...selected].sort((a, b) => a - b),
      reward_cents: Number(reward.value), currency: currency.value.toUpperCase(), assignments_per_run: Number(perRun.value),
      lease_s: Math.round(Number(leaseMin.value) * 60), lifetime_s: Math.round(Number(lifetimeH.value) * 3600),
      auto_approval_delay_s: Math.round(Number(autoH.value) * 3600), priority: Number(priority.value),
      conflict_policy: policy.value, conflict_distance_m: Number(distM.value), conflict_keyframes: Number(distK.value),
      conflict_edit_m: Number(editM.value), requirements, client_token: crypto.randomUUID?.() ?? String(Date.now()),
    };
    if (useRules.checked) {
      body.rules = { every_n: Number(everyN.value), lock_n: Number(lockN.value), lock_direction: lockDir.value,
        max_move_m: Number(maxMove.value), order_rule: orderRule.value };
    }
    if (!(body.run_ids as number[]).length) {
      formMsg.textContent = "Choose at least one run (in the list or on the map).";
      return;
    }
    try {
      const t = await tasksApi.create(body as TaskCreate);
      formMsg.textContent = `Task ${t.id} created with ${plural(t.counts?.open ?? 0, "assignment")} open.`;
      resetForm();
      void refresh();
    } catch (err) {
      formMsg.textContent = describeError(err);
    }
  });

  /** After a task is made: the form as new (no runs chosen, no requirements), the map where it was. */
  function resetForm() {
    form.reset();
    reqRows.replaceChildren();
    for (const id of [...selected]) toggle(id, false, false);
  }

  function taskRow(t: Task): HTMLElement {
    const counts = Object.entries(t.counts ?? {}).map(([k, v]) => `${k} ${v}`).join(", ") || "—";
    return h("article", { class: "task-item", "data-testid": `task-${t.id}` },
      h("h3", {}, `${t.title} `, h("span", { class: `status status-${t.status}`, "data-testid": "task-status" }, t.status)),
      h("p", { class: "muted" }, `#${t.id} · priority ${t.priority} · ${t.assignments_per_run} per run · ${fmtReward(t.reward_cents, t.currency)} · ends ${fmtTime(t.expires_at)}`),
      t.requirements.length ? h("p", { class: "muted" }, "Requires: ", t.requirements.map(requirementText).join("; ")) : null,
      h("p", {}, "Assignments: ", counts),
      h("table", { class: "table" },
        h("thead", {}, h("tr", {}, h("th", {}, "Run"), h("th", {}, "State"), h("th", {}, "Assignments"), h("th", {}, "Conflicts"), h("th", {}, "Merged revision"))),
        h("tbody", {}, ...(t.runs ?? []).map((r) => h("tr", { "data-testid": `task-run-${r.id}` },
          h("td", {}, h("a", { href: `#/runs/${r.run_id}` }, String(r.run_id))),
          h("td", {}, h("span", { class: `status status-${r.status}`, "data-testid": "run-state" }, r.status)),
          h("td", {}, Object.entries(r.counts ?? {}).map(([k, v]) => `${k} ${v}`).join(", ")),
          h("td", { "data-testid": "run-conflicts" }, r.conflicts?.length ? h("a", { href: `#/tasks/review/${r.id}` }, `${r.conflicts.length} — review`) : "none"),
          h("td", { "data-testid": "merged-revision" }, r.merged_revision === null ? "" : String(r.merged_revision)),
        )))),
      t.status === "assignable" || t.status === "in_progress"
        ? h("button", { type: "button", onclick: async () => { try { await tasksApi.cancel(t.id); void refresh(); } catch (err) { alert(describeError(err)); } } }, "Cancel task")
        : null,
    );
  }

  async function refresh() {
    try {
      const list = await tasksApi.list();
      const full = await Promise.all(list.items.map((t) => tasksApi.get(t.id)));
      tasksBox.replaceChildren(full.length === 0 ? h("p", { class: "muted" }, "No tasks yet.") : h("div", {}, ...full.map(taskRow)));
    } catch (err) {
      tasksBox.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err)));
    }
  }
  void refresh();
  const poll = window.setInterval(() => void refresh(), 3000);
  cleanups.push(() => window.clearInterval(poll));
  return () => cleanups.reverse().forEach((f) => f());
}
