/**
 * Reviewer pages: the queue (conflicts first) and one run's submissions side by side on the
 * map — each operator's corrected track and moves in its own colour, the consensus dashed,
 * keyframes coloured by disagreement — with approve / reject and feedback per submission.
 */
import type * as maplibregl from "maplibre-gl";
import { describeError } from "../api/errors";
import type { AppContext } from "../ui/context";
import { fmtTime, h } from "../ui/dom";
import { createMap, fitBoxes } from "../map/createMap";
import { type ReviewView, tasksApi } from "./api";
import { reviewCommand, trackColour, worstKeyframes } from "./format";

export function renderReviewQueue(main: HTMLElement, _ctx: AppContext): () => void {
  const box = h("div", { "data-testid": "review-queue" }, h("p", {}, "Loading…"));
  main.append(h("section", { class: "page" }, h("h1", {}, "Review"), h("section", { class: "card" }, box)));
  const load = () => tasksApi.reviewQueue().then(
    (rows) => box.replaceChildren(rows.length === 0 ? h("p", { class: "muted" }, "Nothing to review.") :
      h("table", { class: "table" },
        h("thead", {}, h("tr", {}, h("th", {}, "Task"), h("th", {}, "Run"), h("th", {}, "State"), h("th", {}, "Submissions"), h("th", {}, "Conflicts"))),
        h("tbody", {}, ...rows.map((r) => h("tr", {},
          h("td", {}, h("a", { href: `#/tasks/review/${r.task_run_id}`, "data-testid": `review-${r.task_run_id}` }, r.task_title)),
          h("td", {}, String(r.run_id)),
          h("td", {}, h("span", { class: `status status-${r.status}` }, r.status)),
          h("td", {}, String(r.submitted)),
          h("td", {}, String(r.conflicts))))))),
    (err) => box.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
  );
  void load();
  const poll = window.setInterval(() => void load(), 5000);
  return () => window.clearInterval(poll);
}

function line(coords: number[][], props: Record<string, unknown>): GeoJSON.Feature {
  return { type: "Feature", properties: props, geometry: { type: "LineString", coordinates: coords } };
}

function point(c: number[], props: Record<string, unknown>): GeoJSON.Feature {
  return { type: "Feature", properties: props, geometry: { type: "Point", coordinates: c } };
}

/** GeoJSON of a review: reported, each submission, consensus, moves and per-keyframe disagreement. */
export function reviewGeoJSON(v: ReviewView): GeoJSON.FeatureCollection {
  const feats: GeoJSON.Feature[] = [line(v.reported, { kind: "reported", colour: "#64748b" })];
  v.submissions.forEach((s, i) => {
    if (s.positions) feats.push(line(s.positions, { kind: "track", colour: trackColour(i), who: s.operator ?? "", aid: s.assignment_id }));
    for (const m of s.moves as number[][]) feats.push(point([m[1], m[2]], { kind: "move", colour: trackColour(i), k: m[0], aid: s.assignment_id }));
  });
  if (v.consensus) {
    feats.push(line(v.consensus, { kind: "consensus", colour: "#111827" }));
    v.consensus.forEach((c, k) => feats.push(point(c, { kind: "kf", d: v.disagreement_m?.[k] ?? 0, k })));
  }
  return { type: "FeatureCollection", features: feats };
}

function disagreementChart(d: number[]): HTMLCanvasElement {
  const c = h("canvas", { width: 600, height: 90, class: "disagreement-chart", "aria-label": "Disagreement (m) per keyframe", role: "img" });
  const g = c.getContext("2d");
  if (!g || d.length === 0) return c;
  const max = Math.max(...d, 1);
  const w = c.width / d.length;
  d.forEach((v, i) => {
    g.fillStyle = v > 5 ? "#dc2626" : v > 2 ? "#f59e0b" : "#16a34a";
    const hgt = (v / max) * (c.height - 12);
    g.fillRect(i * w, c.height - hgt, Math.max(w - 0.5, 0.5), hgt);
  });
  g.fillStyle = "#334155";
  g.font = "11px sans-serif";
  g.fillText(`max ${max.toFixed(1)} m`, 4, 11);
  return c;
}

export function renderReview(main: HTMLElement, ctx: AppContext, taskRunId: number): () => void {
  const cleanups: (() => void)[] = [];
  const head = h("div", { class: "review-head" }, h("p", {}, "Loading…"));
  const mapEl = h("div", { class: "review-map", "aria-label": "Submissions on the map" });
  const side = h("aside", { class: "review-side", "aria-label": "Submissions" });
  const legend = h("ul", { class: "review-legend", "aria-label": "Map legend", "data-testid": "review-legend" },
    h("li", {}, h("span", { class: "line-swatch", style: { background: "#64748b" } }), "reported track"),
    h("li", {}, h("span", { class: "line-swatch", style: { background: trackColour(0) } }), "an operator's corrected track (colour as in the list)"),
    h("li", {}, h("span", { class: "line-swatch consensus" }), "consensus (dashed)"),
    h("li", {}, h("span", { class: "dot", style: { background: trackColour(0), border: "1.5px solid #111" } }), "a keyframe an operator moved"),
    h("li", {}, h("span", { class: "dot", style: { background: "#16a34a" } }), h("span", { class: "dot", style: { background: "#f59e0b" } }),
      h("span", { class: "dot", style: { background: "#dc2626" } }), "keyframes by disagreement: under 2 m, 2–5 m, over 5 m"));
  main.append(h("section", { class: "review" }, head, h("div", { class: "review-body" }, h("div", { class: "review-map-wrap" }, mapEl, legend), side)));
  let map: maplibregl.Map | null = null;
  let alive = true;
  cleanups.push(() => {
    alive = false;
    map?.remove();
  });

  // Keyboard review: the focused submission, whether the map shows it alone, a pending reject.
  let focusAt = 0;
  let solo = false;
  let lastJson = "";
  let view: ReviewView | null = null;
  const cards = new Map<number, { el: HTMLElement; fb: HTMLInputElement; msg: HTMLElement }>();
  const keyMsg = h("p", { class: "muted", role: "status", "data-testid": "review-keys-msg" });
  const pendingIds = () => (view?.submissions ?? []).filter((x) => x.status === "submitted").map((x) => x.assignment_id);

  function focusCard(): void {
    const ids = pendingIds();
    if (ids.length === 0) {
      keyMsg.textContent = "Every submission of this run is reviewed. N: next run in the queue.";
      return;
    }
    focusAt = Math.max(0, Math.min(focusAt, ids.length - 1));
    for (const [id, c] of cards) c.el.classList.toggle("focused", id === ids[focusAt]);
    const c = cards.get(ids[focusAt]);
    c?.el.scrollIntoView({ block: "nearest" });
    keyMsg.textContent = `Submission ${focusAt + 1} of ${ids.length} (${c?.el.dataset.operator ?? ""}). J/K: next/previous · A: approve · R: reject (needs a reason) · S: show it alone · N: next run`;
    showSolo();
  }

  function showSolo(): void {
    if (!map || !map.getLayer("rv-tracks")) return;
    const id = pendingIds()[focusAt];
    const f = solo && id !== undefined ? (["==", ["get", "aid"], id] as never) : null;
    map.setFilter("rv-tracks", f ? (["all", ["==", ["get", "kind"], "track"], f] as never) : (["==", ["get", "kind"], "track"] as never));
    map.setFilter("rv-moves", f ? (["all", ["==", ["get", "kind"], "move"], f] as never) : (["==", ["get", "kind"], "move"] as never));
  }

  async function decide(id: number, d: "approve" | "reject"): Promise<void> {
    const c = cards.get(id);
    if (!c) return;
    if (d === "reject" && !c.fb.value.trim()) {
      c.msg.textContent = "A rejection needs a reason: type it, then press Enter.";
      c.fb.dataset.rejectPending = "true";
      c.fb.focus();
      return;
    }
    try {
      await tasksApi.review(id, d, c.fb.value);
      await load();
    } catch (err) {
      c.msg.textContent = describeError(err);
    }
  }

  async function nextRun(): Promise<void> {
    try {
      const q = await tasksApi.reviewQueue();
      const next = q.find((x) => x.task_run_id !== taskRunId);
      if (next) ctx.navigate(`#/tasks/review/${next.task_run_id}`);
      else keyMsg.textContent = "Nothing else to review.";
    } catch (err) {
      keyMsg.textContent = describeError(err);
    }
  }

  const onKey = (e: KeyboardEvent) => {
    const t = e.target as HTMLElement | null;
    if (t && (t.tagName === "INPUT" || t.tagName === "TEXTAREA" || t.tagName === "SELECT" || t.closest?.("dialog[open]"))) return;
    const c = reviewCommand(e);
    if (c === null) return;
    const ids = pendingIds();
    if (c === "next") focusAt = Math.min(focusAt + 1, Math.max(ids.length - 1, 0));
    else if (c === "previous") focusAt = Math.max(focusAt - 1, 0);
    else if (c === "approve" && ids.length) void decide(ids[focusAt], "approve");
    else if (c === "reject" && ids.length) void decide(ids[focusAt], "reject");
    else if (c === "solo") solo = !solo;
    else if (c === "next-run") void nextRun();
    e.preventDefault();
    if (c !== "reject") focusCard();
  };
  window.addEventListener("keydown", onKey);
  cleanups.push(() => window.removeEventListener("keydown", onKey));

  async function load() {
    let v: ReviewView;
    try {
      v = await tasksApi.reviewView(taskRunId);
    } catch (err) {
      head.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err)));
      return;
    }
    const json = JSON.stringify(v);
    if (json === lastJson) return; // a poll with nothing new keeps typed feedback and focus
    lastJson = json;
    view = v;
    head.replaceChildren(h("div", {},
      h("h1", {}, `Task ${v.task_id} · run ${v.run_id} `, h("span", { class: `status status-${v.status}`, "data-testid": "review-state" }, v.status)),
      v.merged_revision !== null ? h("p", { "data-testid": "review-merged" }, `Merged as revision ${v.merged_revision}.`) : null,
      mergeNote(v),
      v.conflicts?.length
        ? h("ul", { class: "conflicts", "data-testid": "conflicts" }, ...v.conflicts.map((c) => h("li", {},
            c.kind === "off_consensus"
              ? `Assignment ${c.a} is ${Number(c.distance_m).toFixed(1)} m from the weighted consensus of the others; its operator's accuracy explains ${Number(c.expected_m).toFixed(1)} m`
            : c.kind === "edits_apart"
              ? `Keyframe ${c.index} moved ${Number(c.distance_m).toFixed(1)} m apart by assignments ${c.a} and ${c.b}`
              : `Tracks of assignments ${c.a} and ${c.b} are up to ${Number(c.max_separation_m).toFixed(1)} m apart over keyframes ${c.first}–${c.last}`)))
        : h("p", { class: "muted" }, "No conflict."),
      keyMsg,
    ));
    const worst = worstKeyframes(v.disagreement_m ?? [], 8, 0.5);
    cards.clear();
    side.replaceChildren(h("div", {},
      h("h2", {}, "Disagreement per keyframe"),
      disagreementChart(v.disagreement_m ?? []),
      worst.length ? h("table", { class: "table", "data-testid": "worst" },
        h("thead", {}, h("tr", {}, h("th", {}, "Keyframe"), h("th", {}, "Apart (m)"))),
        h("tbody", {}, ...worst.map(([k, d]) => h("tr", {}, h("td", {}, String(k)), h("td", {}, d.toFixed(2)))))) : null,
      h("h2", {}, "Submissions"),
      ...v.submissions.map((s, i) => {
        const id = s.assignment_id;
        const fb = h("input", { placeholder: "Feedback (required to reject)", "aria-label": `Feedback for ${s.operator ?? id}`, "data-testid": `feedback-${id}` });
        fb.addEventListener("keydown", (e) => {
          if (e.key === "Enter" && fb.dataset.rejectPending === "true") void decide(id, "reject");
          if (e.key === "Escape") fb.blur();
        });
        const msg = h("span", { role: "status", "data-testid": `decide-msg-${id}` });
        const el = h("article", { class: "submission", "data-testid": `submission-${id}`, "data-operator": s.operator ?? "?" },
          h("h3", {}, h("span", { class: "swatch", style: { background: trackColour(i) } }), ` ${s.operator ?? "?"} `,
            h("span", { class: `status status-${s.status}` }, s.status)),
          h("p", { class: "muted" }, `${s.moves.length} move${s.moves.length === 1 ? "" : "s"}, ${s.deleted.length} deleted · ${fmtTime(s.submitted_at)}`,
            s.consensus_error_m !== null ? ` · ${s.consensus_error_m.toFixed(2)} m from consensus` : ""),
          weighing(s),
          s.comment ? h("p", {}, `“${s.comment}”`) : null,
          s.status === "submitted"
            ? h("div", { class: "decide" }, fb,
                h("button", { type: "button", class: "primary", "data-testid": `approve-${id}`, onclick: () => void decide(id, "approve") }, "Approve"),
                h("button", { type: "button", "data-testid": `reject-${id}`, onclick: () => void decide(id, "reject") }, "Reject"), msg)
            : null,
        );
        cards.set(id, { el, fb, msg });
        return el;
      }),
    ));
    focusCard();
    await drawMap(v);
  }

  /** Why a decided run was not merged, or why its merge failed (with a way to merge again). */
  function mergeNote(v: ReviewView): HTMLElement | null {
    const d = (v.merge_detail ?? {}) as Record<string, unknown>;
    if (v.status === "unmerged" && d.stopped)
      return h("p", { class: "error", "data-testid": "review-stopped" }, `Not merged: ${String(d.stopped)}.`);
    if (v.status !== "merge_failed") return null;
    const msg = h("span", { role: "status" });
    const again = h("button", { type: "button", "data-testid": "merge-again" }, "Merge again");
    again.addEventListener("click", async () => {
      try {
        await tasksApi.mergeAgain(v.task_run_id);
        await load();
      } catch (err) {
        msg.textContent = describeError(err);
      }
    });
    return h("p", { class: "error", role: "alert", "data-testid": "review-merge-failed" },
      `The merge failed: ${String(d.failed ?? "its revision could not be written")}. `, again, " ", msg);
  }

  /** Rank, weight in the consensus, and the operator's measured accuracy beside their distance. */
  function weighing(s: ReviewView["submissions"][number]) {
    if (s.rank == null) return null;
    const acc = s.accuracy_m != null ? `accuracy ${s.accuracy_m.toFixed(2)} m on ${s.gold_scored ?? 0} gold run(s)` : "accuracy not measured";
    return h("p", { class: "weighing", "data-testid": `weighing-${s.assignment_id}` },
      `#${s.rank} · ${s.distance_m != null ? `${s.distance_m.toFixed(2)} m from the weighted consensus` : ""}`,
      s.expected_m != null ? ` (accuracy explains ${s.expected_m.toFixed(2)} m)` : "",
      ` · ${acc}`, s.weight != null ? ` · weight ${Math.round(s.weight * 100)} %` : "",
      s.off_consensus ? h("strong", { class: "off", "data-testid": `off-${s.assignment_id}` }, " · off the consensus: held for review") : null);
  }

  async function drawMap(v: ReviewView) {
    const data = reviewGeoJSON(v);
    if (map) {
      (map.getSource("review") as maplibregl.GeoJSONSource | undefined)?.setData(data);
      return;
    }
    const made = await createMap(mapEl, { center: v.reported[0] as [number, number] | undefined, zoom: 15, navigation: true, compactAttribution: true, exposeAs: "__posefixReviewMap", alive: () => alive });
    if (!made) return;
    if (map) {
      made.map.remove(); // an earlier poll made it meanwhile
      return;
    }
    const m = made.map;
    map = m;
    m.on("load", () => {
      m.addSource("review", { type: "geojson", data });
      m.addLayer({ id: "rv-reported", type: "line", source: "review", filter: ["==", ["get", "kind"], "reported"],
        paint: { "line-color": ["get", "colour"], "line-width": 2, "line-opacity": 0.6 } });
      m.addLayer({ id: "rv-tracks", type: "line", source: "review", filter: ["==", ["get", "kind"], "track"],
        paint: { "line-color": ["get", "colour"], "line-width": 3 } });
      m.addLayer({ id: "rv-consensus", type: "line", source: "review", filter: ["==", ["get", "kind"], "consensus"],
        paint: { "line-color": "#111827", "line-width": 2, "line-dasharray": [2, 2] } });
      m.addLayer({ id: "rv-kf", type: "circle", source: "review", filter: ["==", ["get", "kind"], "kf"],
        paint: { "circle-radius": 4, "circle-color": ["interpolate", ["linear"], ["get", "d"], 0, "#16a34a", 2, "#f59e0b", 5, "#dc2626"],
          "circle-stroke-color": "#fff", "circle-stroke-width": 1 } });
      m.addLayer({ id: "rv-moves", type: "circle", source: "review", filter: ["==", ["get", "kind"], "move"],
        paint: { "circle-radius": 6, "circle-color": ["get", "colour"], "circle-stroke-color": "#111", "circle-stroke-width": 1.5 } });
      fitBoxes(m, v.reported.map((c) => [c[0], c[1], c[0], c[1]]));
      mapEl.dataset.ready = "true";
      showSolo();
    });
  }

  void load();
  const poll = window.setInterval(() => void load(), 4000);
  cleanups.push(() => window.clearInterval(poll));
  return () => cleanups.reverse().forEach((f) => f());
}
