/**
 * Operator pages: "Get next task" (with the reasons when there is none), my leases and my
 * statistics (#/tasks/work), and one assignment in the editor (#/tasks/work/ID) with the
 * task's instructions, a visible lease timer, extend, return and submit.
 */
import { editsBody } from "../api/convert";
import { describeError } from "../api/errors";
import type { AppContext } from "../ui/context";
import { fmtTime, h, plural } from "../ui/dom";
import { renderEditor } from "../ui/editor/view";
import { type OperatorStats, tasksApi } from "./api";
import { fmtRemaining, fmtReward, leaseUrgent, remainingAt } from "./format";

const num = (v: number | null, digits = 2, unit = "") => (v === null || v === undefined ? "—" : `${v.toFixed(digits)}${unit}`);

export function statsCard(s: OperatorStats): HTMLElement {
  return h("dl", { class: "stats", "data-testid": "my-stats" },
    h("dt", {}, "Submitted"), h("dd", {}, String(s.submitted)),
    h("dt", {}, "Approved"), h("dd", {}, String(s.approved)),
    h("dt", {}, "Rejected"), h("dd", {}, String(s.rejected)),
    h("dt", {}, "Accuracy on gold runs"), h("dd", {}, s.gold_scored ? `${num(s.accuracy_m)} m (${plural(s.gold_scored, "run")})` : "not measured yet"),
    h("dt", {}, "Distance to consensus"), h("dd", {}, num(s.agreement_m, 2, " m")),
    h("dt", {}, "Throughput"), h("dd", {}, s.throughput_per_h === null ? "—" : `${s.throughput_per_h.toFixed(1)} per hour`),
    h("dt", {}, "Qualification test"), h("dd", {}, s.test_status.replace("_", " ")),
  );
}

export function renderWork(main: HTMLElement, ctx: AppContext): void {
  const out = h("div", { "aria-live": "polite", "data-testid": "next-result" });
  const leases = h("div", {}, h("p", {}, "Loading…"));
  const stats = h("div");
  const nextBtn = h("button", { type: "button", class: "primary", "data-testid": "next-task" }, "Get next task");
  nextBtn.addEventListener("click", async () => {
    nextBtn.disabled = true;
    out.replaceChildren(h("p", {}, "Looking for work…"));
    try {
      const r = await tasksApi.next();
      if (r.assignment) {
        ctx.navigate(`#/tasks/work/${r.assignment.id}`);
        return;
      }
      out.replaceChildren(h("div", {},
        h("p", { role: "status", "data-testid": "next-message" }, r.message),
        r.ineligible?.length
          ? h("ul", { "data-testid": "ineligible" }, ...(r.ineligible as { title: string; reasons: string[] }[]).map((t) =>
              h("li", {}, h("strong", {}, t.title), ": ", t.reasons.join("; "))))
          : null,
      ));
    } catch (err) {
      out.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err)));
    } finally {
      nextBtn.disabled = false;
    }
  });
  main.append(h("section", { class: "page" },
    h("h1", {}, "Work"),
    h("section", { class: "card" }, h("p", {}, "Ask for the next correction task you qualify for."), nextBtn, out),
    h("section", { class: "card", "aria-labelledby": "leases-h" }, h("h2", { id: "leases-h" }, "My assignments"), leases),
    h("section", { class: "card", "aria-labelledby": "stats-h" }, h("h2", { id: "stats-h" }, "My statistics"), stats),
  ));
  tasksApi.mine().then(
    (rows) => leases.replaceChildren(rows.length === 0 ? h("p", { class: "muted" }, "None yet.") :
      h("table", { class: "table", "data-testid": "my-assignments" },
        h("thead", {}, h("tr", {}, h("th", {}, "Task"), h("th", {}, "Run"), h("th", {}, "Status"), h("th", {}, "Feedback"), h("th", {}, "Leased"))),
        h("tbody", {}, ...rows.map((a) => h("tr", {},
          h("td", {}, a.status === "accepted" ? h("a", { href: `#/tasks/work/${a.id}` }, a.task.title) : a.task.title),
          h("td", {}, String(a.run_id)),
          h("td", {}, h("span", { class: `status status-${a.status}` }, a.status)),
          h("td", { "data-testid": `feedback-${a.id}` }, a.feedback ?? ""),
          h("td", {}, fmtTime(a.leased_at)),
        ))))),
    (err) => leases.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
  );
  tasksApi.me().then((s) => stats.replaceChildren(statsCard(s)), (err) => stats.replaceChildren(h("p", { class: "muted" }, describeError(err))));
}

export function renderAssignment(main: HTMLElement, ctx: AppContext, assignmentId: number): () => void {
  const cleanups: (() => void)[] = [];
  const bar = h("section", { class: "task-bar", "aria-label": "Task" }, h("p", {}, "Loading the assignment…"));
  const host = h("div", { class: "task-editor" });
  main.append(bar, host);
  let timer: number | undefined;
  cleanups.push(() => window.clearInterval(timer));

  tasksApi.assignment(assignmentId).then((a) => {
    if (a.status !== "accepted") {
      bar.replaceChildren(h("p", { role: "status", "data-testid": "assignment-closed" },
        `This assignment is ${a.status}.`, a.feedback ? h("span", { "data-testid": "assignment-feedback" }, ` Reviewer's reason: “${a.feedback}”.`) : "", " ", h("a", { href: "#/tasks/work" }, "Back to work")));
      return;
    }
    let loadedAt = Date.now();
    let remaining0 = a.lease_remaining_s ?? 0;
    const leaseS = a.lease_expires_at && a.leased_at ? (Date.parse(a.lease_expires_at) - Date.parse(a.leased_at)) / 1000 : remaining0;
    const clock = h("span", { class: "lease-timer", "data-testid": "lease-timer", role: "timer", "aria-live": "off" }, fmtRemaining(remaining0));
    const msg = h("span", { class: "task-msg", role: "status", "data-testid": "task-msg" });
    let leaseOver = false;
    let submitted = false;
    const extendBtn = h("button", { type: "button", "data-testid": "extend" }, "Extend lease");
    const returnBtn = h("button", { type: "button", "data-testid": "return" }, "Return");
    const nextBtn = h("button", { type: "button", class: "primary", "data-testid": "offer-next", hidden: true }, "Next task");
    nextBtn.addEventListener("click", async () => {
      nextBtn.disabled = true;
      try {
        const r = await tasksApi.next();
        if (r.assignment) ctx.navigate(`#/tasks/work/${r.assignment.id}`);
        else msg.replaceChildren(r.message, " ", h("a", { href: "#/tasks/work" }, "Back to work"));
      } catch (err) {
        msg.textContent = describeError(err);
      } finally {
        nextBtn.disabled = false;
      }
    });
    extendBtn.addEventListener("click", async () => {
      try {
        const x = await tasksApi.extend(a.id);
        remaining0 = x.lease_remaining_s ?? 0;
        loadedAt = Date.now();
        msg.textContent = `Lease extended to ${fmtTime(x.lease_expires_at)}.`;
      } catch (err) {
        msg.textContent = describeError(err);
      }
    });
    returnBtn.addEventListener("click", async () => {
      try {
        await tasksApi.giveBack(a.id);
        ctx.navigate("#/tasks/work");
      } catch (err) {
        msg.textContent = describeError(err);
      }
    });
    const tick = () => {
      const left = remainingAt(remaining0, loadedAt, Date.now());
      clock.textContent = fmtRemaining(left);
      clock.classList.toggle("urgent", leaseUrgent(left, leaseS));
      if (left <= 0 && !submitted) {
        leaseOver = true;
        extendBtn.disabled = true;
        msg.textContent = "The lease is over: this work can no longer be submitted.";
      }
    };
    timer = window.setInterval(tick, 1000);
    bar.replaceChildren(
      h("div", { class: "task-head" },
        h("strong", { "data-testid": "task-title" }, a.task.title),
        h("span", { class: "muted" }, ` · run ${a.run_id} · reward ${fmtReward(a.task.reward_cents, a.task.currency)} · lease `),
        clock, h("span", { class: "grow" }), extendBtn, returnBtn, nextBtn),
      h("details", { open: true }, h("summary", {}, "Instructions"),
        h("p", { class: "instructions", "data-testid": "instructions" }, a.task.instructions || "No instructions.")),
      msg,
    );
    cleanups.push(renderEditor(host, ctx, String(a.run_id), (ctl) => {
      ctl.submitTo = async (_doc, edits, c) => {
        if (leaseOver) throw new Error("The lease is over: this work can no longer be submitted.");
        if (submitted) throw new Error("This assignment is already submitted.");
        await tasksApi.submit(a.id, { ...editsBody(edits), comment: c || null });
        submitted = true;
        window.clearInterval(timer);
        extendBtn.disabled = returnBtn.disabled = true;
        nextBtn.hidden = false;
        nextBtn.focus();
        msg.replaceChildren("Submitted — thank you. ", h("a", { href: "#/tasks/work", "data-testid": "back-to-work" }, "Back to work"));
        clock.textContent = "submitted";
        return "Submitted to the task.";
      };
    }, { label: "Submit to task", commentLabel: "Comment for the reviewer", testId: "task-submit" }));
  }, (err) => bar.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))));
  return () => cleanups.reverse().forEach((f) => f());
}
