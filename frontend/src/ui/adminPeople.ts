/**
 * Admin: people and, per person, an audit view of what they did (#/admin/people/ID): the
 * edits they submitted (run, revision, comment, task) and the reviews they made.
 */
import { api } from "../api/endpoints";
import { describeError } from "../api/errors";
import type { AppContext } from "./context";
import { fmtTime, h } from "./dom";

export function renderAdminPeople(path: string, main: HTMLElement, _ctx: AppContext): void {
  const m = path.match(/^\/admin\/people\/(\d+)/);
  if (m) return renderActivity(main, Number(m[1]));
  const box = h("div", { "data-testid": "people" }, h("p", {}, "Loading…"));
  main.append(h("section", { class: "page" }, h("h1", {}, "People"), h("section", { class: "card" }, box)));
  api.listUsers().then(
    (r) => box.replaceChildren(h("table", { class: "table" },
      h("thead", {}, h("tr", {}, h("th", {}, "Name"), h("th", {}, "Role"), h("th", {}, "Since"))),
      h("tbody", {}, ...r.items.map((u) => h("tr", {},
        h("td", {}, h("a", { href: `#/admin/people/${u.id}`, "data-testid": `person-${u.username}` }, u.username)),
        h("td", {}, u.role),
        h("td", {}, fmtTime(u.created_at))))))),
    (err) => box.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
  );
}

function renderActivity(main: HTMLElement, userId: number): void {
  const title = h("h1", {}, "Activity");
  const edits = h("div", { "data-testid": "activity-edits" }, h("p", {}, "Loading…"));
  const reviews = h("div", { "data-testid": "activity-reviews" });
  main.append(h("section", { class: "page" },
    h("p", {}, h("a", { href: "#/admin/people" }, "← People")), title,
    h("section", { class: "card" }, h("h2", {}, "Edits submitted"), edits),
    h("section", { class: "card" }, h("h2", {}, "Reviews made"), reviews)));
  api.userActivity(userId).then((a) => {
    title.textContent = `Activity of ${a.username}`;
    edits.replaceChildren(a.edits.length === 0 ? h("p", { class: "muted" }, "No edits.") : h("table", { class: "table" },
      h("thead", {}, h("tr", {}, ...["When", "Run", "Revision", "What", "Comment", "Task"].map((t) => h("th", {}, t)))),
      h("tbody", {}, ...a.edits.map((e) => h("tr", {},
        h("td", {}, fmtTime(e.created_at)),
        h("td", {}, h("a", { href: `#/runs/${e.run_id}` }, e.run_name)),
        h("td", {}, String(e.revision)),
        h("td", {}, e.kind === "revert" ? "revert" : `${e.n_moves} move${e.n_moves === 1 ? "" : "s"}, ${e.n_deleted} deleted${e.accept ? ", accepted as is" : ""}`),
        h("td", {}, e.comment ?? ""),
        h("td", {}, e.task_id === null ? "" : String(e.task_id)))))));
    reviews.replaceChildren(a.reviews.length === 0 ? h("p", { class: "muted" }, "No reviews.") : h("table", { class: "table" },
      h("thead", {}, h("tr", {}, ...["When", "Run", "Of", "Decision", "Feedback"].map((t) => h("th", {}, t)))),
      h("tbody", {}, ...a.reviews.map((r) => h("tr", {},
        h("td", {}, fmtTime(r.at)),
        h("td", {}, h("a", { href: `#/runs/${r.run_id}` }, r.run_name)),
        h("td", {}, r.target === "assignment" ? `task ${r.task_id} submission ${r.assignment_id}` : `revision ${r.revision}`),
        h("td", {}, h("span", { class: `status status-${r.decision}` }, r.decision)),
        h("td", {}, r.comment ?? ""))))));
  }, (err) => edits.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))));
}
