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
import { trackColour, worstKeyframes } from "./format";

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
    if (s.positions) feats.push(line(s.positions, { kind: "track", colour: trackColour(i), who: s.operator ?? "" }));
    for (const m of s.moves as number[][]) feats.push(point([m[1], m[2]], { kind: "move", colour: trackColour(i), k: m[0] }));
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
  main.append(h("section", { class: "review" }, head, h("div", { class: "review-body" }, mapEl, side)));
  let map: maplibregl.Map | null = null;
  let alive = true;
  cleanups.push(() => {
    alive = false;
    map?.remove();
  });

  async function load() {
    let v: ReviewView;
    try {
      v = await tasksApi.reviewView(taskRunId);
    } catch (err) {
      head.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err)));
      return;
    }
    head.replaceChildren(h("div", {},
      h("h1", {}, `Task ${v.task_id} · run ${v.run_id} `, h("span", { class: `status status-${v.status}`, "data-testid": "review-state" }, v.status)),
      v.merged_revision !== null ? h("p", { "data-testid": "review-merged" }, `Merged as revision ${v.merged_revision}.`) : null,
      v.conflicts?.length
        ? h("ul", { class: "conflicts", "data-testid": "conflicts" }, ...v.conflicts.map((c) => h("li", {},
            c.kind === "edits_apart"
              ? `Keyframe ${c.index} moved ${Number(c.distance_m).toFixed(1)} m apart by assignments ${c.a} and ${c.b}`
              : `Tracks of assignments ${c.a} and ${c.b} are up to ${Number(c.max_separation_m).toFixed(1)} m apart over keyframes ${c.first}–${c.last}`)))
        : h("p", { class: "muted" }, "No conflict."),
    ));
    const worst = worstKeyframes(v.disagreement_m ?? [], 8, 0.5);
    side.replaceChildren(h("div", {},
      h("h2", {}, "Disagreement per keyframe"),
      disagreementChart(v.disagreement_m ?? []),
      worst.length ? h("table", { class: "table", "data-testid": "worst" },
        h("thead", {}, h("tr", {}, h("th", {}, "Keyframe"), h("th", {}, "Apart (m)"))),
        h("tbody", {}, ...worst.map(([k, d]) => h("tr", {}, h("td", {}, String(k)), h("td", {}, d.toFixed(2)))))) : null,
      h("h2", {}, "Submissions"),
      ...v.submissions.map((s, i) => {
        const fb = h("input", { placeholder: "Feedback", "aria-label": `Feedback for ${s.operator ?? s.assignment_id}` });
        const msg = h("span", { role: "status" });
        const decide = async (d: "approve" | "reject") => {
          try {
            await tasksApi.review(s.assignment_id, d, fb.value);
            void load();
          } catch (err) {
            msg.textContent = describeError(err);
          }
        };
        return h("article", { class: "submission", "data-testid": `submission-${s.assignment_id}` },
          h("h3", {}, h("span", { class: "swatch", style: { background: trackColour(i) } }), ` ${s.operator ?? "?"} `,
            h("span", { class: `status status-${s.status}` }, s.status)),
          h("p", { class: "muted" }, `${s.moves.length} moves, ${s.deleted.length} deleted · ${fmtTime(s.submitted_at)}`,
            s.consensus_error_m !== null ? ` · ${s.consensus_error_m.toFixed(2)} m from consensus` : ""),
          s.comment ? h("p", {}, `“${s.comment}”`) : null,
          s.status === "submitted"
            ? h("div", { class: "decide" }, fb,
                h("button", { type: "button", class: "primary", "data-testid": `approve-${s.assignment_id}`, onclick: () => void decide("approve") }, "Approve"),
                h("button", { type: "button", "data-testid": `reject-${s.assignment_id}`, onclick: () => void decide("reject") }, "Reject"), msg)
            : null,
        );
      }),
    ));
    await drawMap(v);
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
    });
  }

  void load();
  const poll = window.setInterval(() => void load(), 4000);
  cleanups.push(() => window.clearInterval(poll));
  void ctx;
  return () => cleanups.reverse().forEach((f) => f());
}
