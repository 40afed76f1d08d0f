/**
 * Floor plan pages: #/floors (list, admin upload with the model job's progress) and
 * #/floors/ID (the floor image in its metric frame on a canvas — works offline — with a
 * walk's matched track, the raw dead-reckoning track, the 2σ uncertainty ellipse, a
 * step-by-step replay (play/pause/scrub) and the error at each surveyed waypoint). Walks
 * are tracked in the browser (src/tracker, from the downloaded model), the server's answer
 * on request beside it; "Track me" tracks the phone itself from its motion sensors.
 */
import { describeError } from "../api/errors";
import type { AppContext } from "../ui/context";
import { clear, fmtTime, h, plural } from "../ui/dom";
import { type FloorPlan, type WalkStep, type WalkTrack, type WalkWifi, jobResult, mapsApi } from "./api";
import { loadFingerprints } from "../tracker/fingerprints";
import { LiveSession } from "../tracker/live";
import { WalkFormatError, parseWalk } from "../tracker/sensors";
import type { Mode } from "../tracker/modes";
import { trackWalk } from "../tracker/tracker";
import { floorModel, liveTrack, walkTrackFromRun, walkWifi } from "./deviceTrack";
import { FloorMap } from "./floorMap";
import { ellipsePx, fitBox, fmtM, fromPx, parseStart, reachedWaypoints, toPx, walkBox, type View } from "./floorView";
import { keepFloorsOffline, keepForOffline } from "./offline";
import { askMotionPermission, listenSensors } from "./trackMe";
import "./maps.css";

const STEP_MS = 200;

function kib(n: number | null): string {
  return n === null ? "–" : `${(n / 1024).toFixed(1)} KiB`;
}

export function renderFloorsRoute(path: string, main: HTMLElement, ctx: AppContext): (() => void) | void {
  keepFloorsOffline();
  const m = path.match(/^\/floors\/(\d+)/);
  if (m) return renderFloor(main, ctx, Number(m[1]));
  return renderFloorList(main, ctx);
}

function renderFloorList(main: HTMLElement, ctx: AppContext): () => void {
  let alive = true;
  const list = h("tbody");
  const msg = h("p", { class: "floor-msg", role: "status", "data-testid": "floor-upload-msg" });
  const root = h("section", { class: "floors" }, h("h1", {}, "Floor plans"));
  main.append(root);

  async function load() {
    try {
      const r = await mapsApi.listFloors();
      if (!alive) return;
      clear(list);
      for (const f of r.items) {
        list.append(h("tr", { "data-testid": "floor-row" },
          h("td", {}, h("a", { href: `#/floors/${f.id}` }, f.name)),
          h("td", { "data-testid": "floor-status" }, f.status === "failed" ? `failed: ${f.error ?? ""}` : f.status),
          h("td", {}, f.n_vertices === null ? "–" : String(f.n_vertices)),
          h("td", {}, kib(f.model_bytes)),
          h("td", {}, `${f.width_m.toFixed(1)} × ${f.height_m.toFixed(1)} m`),
          h("td", {}, fmtTime(f.created_at)),
        ));
      }
      if (!r.items.length) list.append(h("tr", {}, h("td", { colspan: "6" }, "No floor plans yet.")));
    } catch (err) {
      msg.textContent = describeError(err);
    }
  }

  if (ctx.user?.role === "admin") {
    const name = h("input", { name: "name", required: true, placeholder: "Name", "aria-label": "Floor plan name" });
    const file = h("input", { type: "file", name: "file", accept: ".zip,.geojson,.json", required: true, "aria-label": "Floor plan file", "data-testid": "floor-file" });
    const cell = h("input", { type: "number", name: "cell_m", value: "0.8", step: "0.1", min: "0.2", max: "5", "aria-label": "Cell size (m)" });
    const submit = h("button", { type: "submit", class: "primary", "data-testid": "floor-upload" }, "Upload");
    const form = h("form", { class: "floor-upload" },
      h("label", {}, "Name ", name), h("label", {}, "Floor (.zip of floor_info.json, geojson_map.json, floor_image.png; or .geojson of walkable polygons in metres) ", file),
      h("label", {}, "Cell size (m) ", cell), submit);
    form.addEventListener("submit", async (e) => {
      e.preventDefault();
      const f = file.files?.[0];
      if (!f) return;
      const fd = new FormData();
      fd.append("name", name.value.trim() || f.name);
      fd.append("cell_m", cell.value);
      fd.append("file", f, f.name);
      submit.disabled = true;
      msg.textContent = "Uploading…";
      try {
        const fp = await mapsApi.uploadFloor(fd);
        await load();
        const done = await followJob(fp, (t) => (msg.textContent = t), () => alive);
        await load(); // the list shows the new status before the message says so
        msg.textContent = done;
      } catch (err) {
        msg.textContent = `Upload refused: ${describeError(err)}`;
      } finally {
        submit.disabled = false;
      }
    });
    root.append(h("h2", {}, "Upload a floor plan"), form);
  }
  root.append(msg, h("table", { class: "floor-table" },
    h("thead", {}, h("tr", {}, ...["Name", "Model", "Vertices", "Model size", "Extent", "Uploaded"].map((t) => h("th", {}, t)))), list));
  void load();
  return () => {
    alive = false;
  };
}

/** Follow the model job; returns the sentence to show when it has finished. */
async function followJob(fp: FloorPlan, say: (t: string) => void, alive: () => boolean): Promise<string> {
  if (fp.job_id === null) return `“${fp.name}” uploaded.`;
  try {
    await jobResult(fp.job_id, (f, m) => say(`Building the model… ${Math.round(f * 100)}%${m ? ` (${m})` : ""}`), alive, 300, 300_000);
    return `Model of “${fp.name}” built.`;
  } catch (err) {
    return `The model could not be built: ${(err as Error).message}`;
  }
}

function renderFloor(main: HTMLElement, _ctx: AppContext, id: number): () => void {
  let alive = true;
  let timer: number | undefined;
  let fp: FloorPlan | null = null;
  let track: WalkTrack | null = null;
  let step = 0;
  let image: HTMLImageElement | null = null;
  let zoomed = false; // to the walk, or the whole floor
  let view: View | null = null;
  let modes: Mode[] | null = null; // a live session's modes while it has not converged
  let live: { session: LiveSession; stop: () => void } | null = null;

  const floorMap = new FloorMap(() => alive);
  const title = h("h1", {}, "Floor plan");
  const meta = h("p", { class: "floor-meta", "data-testid": "floor-meta" });
  const canvas = h("canvas", { class: "floor-canvas", width: 900, height: 660, "data-testid": "floor-canvas", "aria-label": "Floor plan with the tracked walk" });
  const walkFile = h("input", { type: "file", accept: ".txt", "aria-label": "Walk file", "data-testid": "walk-file" });
  const surveyFile = h("input", { type: "file", accept: ".npz", "aria-label": "WiFi survey (fingerprint file, optional)", "data-testid": "walk-fingerprints" });
  const start = h("select", { "aria-label": "Start", "data-testid": "walk-start" },
    h("option", { value: "first_waypoint" }, "Known start (first waypoint)"), h("option", { value: "unknown" }, "Unknown start"));
  const trackBtn = h("button", { type: "button", class: "primary", "data-testid": "walk-track" }, "Track walk");
  const serverBtn = h("button", { type: "button", "data-testid": "walk-server", disabled: true }, "Compare with the server");
  const serverLine = h("p", { "data-testid": "server-error-mean" });
  const startField = h("input", { "aria-label": "Start (x,y in metres; tap the map)", placeholder: "tap the map, or x,y (m)", "data-testid": "track-start", inputmode: "decimal" });
  const meBtn = h("button", { type: "button", class: "primary", "data-testid": "track-me" }, "Track me");
  const stopBtn = h("button", { type: "button", "data-testid": "track-stop", disabled: true }, "Stop");
  const liveMsg = h("p", { class: "floor-msg", role: "status", "data-testid": "live-msg" });
  const msg = h("p", { class: "floor-msg", role: "status", "data-testid": "walk-msg" });
  const play = h("button", { type: "button", "data-testid": "replay-play", disabled: true }, "▶ Play");
  const scrub = h("input", { type: "range", min: "0", max: "0", value: "0", "aria-label": "Step", "data-testid": "replay-scrub", disabled: true });
  const stepLabel = h("span", { "data-testid": "replay-step" }, "");
  const zoomBtn = h("button", { type: "button", "data-testid": "floor-zoom", disabled: true }, "Whole floor");
  zoomBtn.addEventListener("click", () => {
    zoomed = !zoomed;
    zoomBtn.textContent = zoomed ? "Whole floor" : "Zoom to walk";
    draw();
  });
  const summary = h("div", { class: "walk-summary", "data-testid": "walk-summary" });
  const errTable = h("tbody", { "data-testid": "walk-errors" });
  const legend = h("ul", { class: "floor-legend" },
    h("li", {}, h("span", { class: "sw matched" }), "matched track (CRF)"),
    h("li", {}, h("span", { class: "sw dr" }), "dead reckoning"),
    h("li", {}, h("span", { class: "sw ellipse" }), "2σ uncertainty"),
    h("li", {}, h("span", { class: "sw wp" }), "surveyed waypoint (error)"));
  main.append(h("section", { class: "floor-page" },
    h("p", {}, h("a", { href: "#/floors" }, "← Floor plans")), title, meta,
    h("div", { class: "floor-body" },
      h("div", { class: "floor-left" }, canvas,
        h("div", { class: "replay", role: "group", "aria-label": "Replay" }, play, scrub, stepLabel, zoomBtn),
        h("h2", {}, "On the map"), floorMap.el),
      h("aside", { class: "floor-side" },
        h("h2", {}, "Track me"),
        h("p", {}, "Tracks this phone from its motion sensors, in the browser. Tap your start on the map (or leave it empty: the page then shows every place the steps fit). Works offline once this page and the model are loaded."),
        startField, h("div", { class: "track-me" }, meBtn, stopBtn), liveMsg,
        h("h2", {}, "Track a walk"), h("p", {}, "A walk in the competition's path-file format (.txt), tracked in this browser."), walkFile,
        h("label", {}, "WiFi survey (optional: the .npz of ", h("code", {}, "posefix mapmatch fingerprints"), ")", surveyFile), start, trackBtn, msg,
        summary, serverBtn, serverLine, legend,
        h("table", { class: "floor-table" }, h("thead", {}, h("tr", {}, h("th", {}, "Waypoint"), h("th", {}, "CRF error"), h("th", {}, "Dead reckoning"))), errTable)))));

  function draw() {
    if (fp) floorMap.render(fp, track, step);
    const c = canvas.getContext("2d");
    if (!c || !fp) return;
    const box: [number, number, number, number] = zoomed && track ? walkBox(track) : [0, 0, fp.width_m, fp.height_m];
    const v = fitBox(box, canvas.width, canvas.height);
    view = v;
    canvas.dataset.view = JSON.stringify(v);
    c.clearRect(0, 0, canvas.width, canvas.height);
    c.fillStyle = "#f8fafc";
    c.fillRect(0, 0, canvas.width, canvas.height);
    const [x0, y1] = toPx(v, 0, fp.height_m);
    if (image && image.complete && image.naturalWidth) c.drawImage(image, x0, y1, fp.width_m * v.scale, fp.height_m * v.scale);
    else {
      c.strokeStyle = "#94a3b8";
      c.strokeRect(x0, y1, fp.width_m * v.scale, fp.height_m * v.scale);
    }
    const startXY = parseStart(startField.value);
    if (startXY) {
      const [sx, sy] = toPx(v, startXY[0], startXY[1]);
      c.strokeStyle = "#15803d";
      c.lineWidth = 2;
      c.beginPath();
      c.arc(sx, sy, 7, 0, 2 * Math.PI);
      c.stroke();
    }
    if (!track) return;
    const n = Math.min(step, track.steps.length - 1);
    const line = (pts: [number, number][], color: string, width: number, dash: number[]) => {
      c.beginPath();
      pts.forEach(([x, y], i) => (i ? c.lineTo(x, y) : c.moveTo(x, y)));
      c.setLineDash(dash);
      c.strokeStyle = color;
      c.lineWidth = width;
      c.stroke();
      c.setLineDash([]);
    };
    const upto = track.steps.slice(0, n + 1);
    line(upto.map((s) => toPx(v, s.dr_x_m, s.dr_y_m)), "#64748b", 2, [6, 4]);
    line(upto.map((s) => toPx(v, s.x_m, s.y_m)), "#1d4ed8", 3, []);
    const cur = track.steps[n];
    if (modes && n === track.steps.length - 1) return drawModes(c, v, modes); // no single position to show
    const [cx, cy] = toPx(v, cur.x_m, cur.y_m);
    const e = ellipsePx(v, cur);
    c.beginPath();
    c.ellipse(cx, cy, e.rx, e.ry, e.rotation, 0, 2 * Math.PI);
    c.fillStyle = "rgba(29,78,216,0.15)";
    c.fill();
    c.strokeStyle = "#1d4ed8";
    c.lineWidth = 1.5;
    c.stroke();
    c.beginPath();
    c.arc(cx, cy, 4, 0, 2 * Math.PI);
    c.fillStyle = "#1d4ed8";
    c.fill();
    const reached = new Set(reachedWaypoints(track, n).map((w) => w.t_ms));
    c.font = "12px system-ui, sans-serif";
    for (const w of track.errors.waypoints) {
      const [wx, wy] = toPx(v, w.x_m, w.y_m);
      c.strokeStyle = reached.has(w.t_ms) ? "#dc2626" : "#fca5a5";
      c.lineWidth = 2;
      c.beginPath();
      c.moveTo(wx - 5, wy - 5);
      c.lineTo(wx + 5, wy + 5);
      c.moveTo(wx + 5, wy - 5);
      c.lineTo(wx - 5, wy + 5);
      c.stroke();
      if (reached.has(w.t_ms) && !w.given_start) {
        c.fillStyle = "#991b1b";
        c.fillText(fmtM(w.error_m), wx + 7, wy - 7);
      }
    }
  }

  function setStep(i: number) {
    if (!track) return;
    step = Math.max(0, Math.min(i, track.steps.length - 1));
    scrub.value = String(step);
    const s = track.steps[step];
    const reached = reachedWaypoints(track, step).filter((w) => !w.given_start);
    stepLabel.textContent = `step ${step} / ${track.steps.length - 1} · ${placeText(s)}${reached.length ? ` · last waypoint error ${fmtM(reached[reached.length - 1].error_m)}` : ""}`;
    canvas.dataset.step = String(step);
    canvas.dataset.waypointsReached = String(reached.length);
    draw();
  }

  function stop() {
    window.clearInterval(timer);
    timer = undefined;
    play.textContent = "▶ Play";
    play.setAttribute("aria-pressed", "false");
  }

  play.addEventListener("click", () => {
    if (!track) return;
    if (timer !== undefined) return stop();
    if (step >= track.steps.length - 1) setStep(0);
    play.textContent = "❚❚ Pause";
    play.setAttribute("aria-pressed", "true");
    timer = window.setInterval(() => {
      if (!track) return stop();
      setStep(step + 1);
      if (step >= track.steps.length - 1) stop();
    }, STEP_MS);
  });
  scrub.addEventListener("input", () => {
    stop();
    setStep(Number(scrub.value));
  });

  /** Where the walker is, honestly: a 2σ ellipse when the posterior converged, else how many places and how far apart. */
  function placeText(s: WalkStep): string {
    if (s.converged === undefined) return `2σ ${fmtM(2 * s.sigma_major_m)}`;
    if (s.converged) return `converged · 2σ ${fmtM(2 * s.sigma_major_m)}`;
    return `not converged: ${(s.n_modes ?? 1) > 1 ? `${s.n_modes} places up to ${fmtM(s.mode_spread_m ?? 0)} apart` : `one place, 2σ ${fmtM(2 * s.sigma_major_m)} across`}`;
  }

  /** What the walk's WiFi did: the survey fixes used, or why none (a survey too small to calibrate them). */
  function wifiText(w: WalkWifi): string {
    if (w.used) {
      const cap = w.walk_corr ? `; the whole walk's WiFi counts as at most ${(1 / w.walk_corr).toFixed(1)} fixes, its errors being shared along the walk` : "";
      return `WiFi: ${plural(w.fixes, "scan")} placed by the survey ${w.fingerprints ?? ""}${cap}.`;
    }
    return `WiFi not used: ${w.note}.`;
  }

  function showTrack(t: WalkTrack) {
    track = t;
    stop();
    scrub.max = String(t.steps.length - 1);
    scrub.disabled = play.disabled = zoomBtn.disabled = false;
    zoomed = true;
    zoomBtn.textContent = "Whole floor";
    const e = t.errors;
    summary.replaceChildren(
      h("p", {}, `${t.walk.file}: ${plural(t.walk.n_steps, "step")}, tracked in ${t.walk.track_ms.toFixed(0)} ms (${t.walk.ms_per_step.toFixed(2)} ms per step).`),
      ...(t.walk.converged_at_end === undefined ? [] : [h("p", { "data-testid": "walk-converged" }, t.walk.converged_at_end
        ? `Converged: the walk is placed (${Math.round(100 * (t.walk.converged_share ?? 0))} % of its steps on one place).`
        : `Not placed: ${placeText(t.steps[t.steps.length - 1])} at the end; the track shown is the most likely, not a fix.`)]),
      ...(t.walk.wifi ? [h("p", { "data-testid": "walk-wifi" }, wifiText(t.walk.wifi))] : []),
      e.n
        ? h("p", { "data-testid": "error-mean" }, `Error at ${e.n} waypoint${e.n === 1 ? "" : "s"}: mean ${fmtM(e.mean_m)}, max ${fmtM(e.max_m)} (dead reckoning: mean ${fmtM(e.dr_mean_m)}).`)
        : h("p", { "data-testid": "error-mean" }, "This walk has no surveyed waypoints to measure the error against."),
    );
    clear(errTable);
    e.waypoints.forEach((w, i) => errTable.append(h("tr", {},
      h("td", {}, `${i + 1} (${w.x_m.toFixed(1)}, ${w.y_m.toFixed(1)})${w.given_start ? " start" : ""}`),
      h("td", {}, w.given_start ? "given" : fmtM(w.error_m)), h("td", {}, w.given_start ? "given" : fmtM(w.dr_error_m)))));
    setStep(0);
  }

  trackBtn.addEventListener("click", async () => {
    const f = walkFile.files?.[0];
    if (!f || !fp) {
      msg.textContent = "Choose a walk file first.";
      return;
    }
    trackBtn.disabled = true;
    msg.textContent = "Tracking in this browser…";
    serverLine.textContent = "";
    try {
      const sf = surveyFile.files?.[0] ?? null;
      const [model, text, survey] = await Promise.all([floorModel(fp.id), f.text(), sf ? sf.arrayBuffer() : Promise.resolve(null)]);
      const walk = parseWalk(text, f.name);
      const fpm = sf && survey ? await loadFingerprints(new Uint8Array(survey), sf.name) : null;
      const known = start.value === "first_waypoint";
      if (known && !walk.waypoints.length) throw new Error(`${f.name}: field TYPE_WAYPOINT: no waypoint to start from; choose Unknown start`);
      const run = trackWalk(model, walk, known ? [walk.waypoints[0].x_m, walk.waypoints[0].y_m] : null, fpm);
      if (!alive) return;
      msg.textContent = "";
      stopLive();
      modes = null;
      showTrack(walkTrackFromRun(run, walk, f.name, known, walkWifi(fpm, walk, sf?.name ?? null)));
      serverBtn.disabled = false;
    } catch (err) {
      msg.textContent = err instanceof WalkFormatError || err instanceof Error ? err.message : describeError(err);
    } finally {
      trackBtn.disabled = false;
    }
  });

  // The same file through the server's tracker (its smoothed, offline answer), for comparison.
  serverBtn.addEventListener("click", async () => {
    const f = walkFile.files?.[0];
    if (!f || !fp) return;
    const fd = new FormData();
    fd.append("start", start.value);
    fd.append("file", f, f.name);
    const sf = surveyFile.files?.[0];
    if (sf) fd.append("fingerprints", sf, sf.name);
    serverBtn.disabled = true;
    serverLine.textContent = "Asking the server…";
    try {
      const t = await mapsApi.trackWalk(fp.id, fd);
      const e = t.errors;
      serverLine.textContent = e.n
        ? `Server (smoothed over the whole walk): mean ${fmtM(e.mean_m)} at ${plural(e.n, "waypoint")}, ${t.walk.ms_per_step.toFixed(2)} ms per step; this browser shows the live (filtered) position.`
        : "The server tracked the walk; it has no waypoints to compare.";
      if (t.walk.wifi?.fingerprints) serverLine.textContent += ` Server: ${wifiText(t.walk.wifi)}`;
    } catch (err) {
      serverLine.textContent = `The server could not be asked: ${describeError(err)}`;
    } finally {
      serverBtn.disabled = false;
    }
  });

  canvas.addEventListener("click", (e) => {
    if (!view || !fp || live) return;
    const r = canvas.getBoundingClientRect();
    const [x, y] = fromPx(view, ((e.clientX - r.left) * canvas.width) / r.width, ((e.clientY - r.top) * canvas.height) / r.height);
    if (x < 0 || y < 0 || x > fp.width_m || y > fp.height_m) return;
    startField.value = `${x.toFixed(1)},${y.toFixed(1)}`;
    draw();
  });
  startField.addEventListener("change", () => draw());

  function stopLive() {
    if (!live) return;
    live.stop();
    live = null;
    meBtn.disabled = false;
    stopBtn.disabled = true;
  }

  function showLive(final = false) {
    if (!live) return;
    const pts = live.session.points;
    const last = pts[pts.length - 1];
    modes = last.converged ? null : last.modes;
    track = liveTrack(pts);
    (window as unknown as { __posefixLiveTrack?: unknown }).__posefixLiveTrack = track.steps;
    scrub.max = String(track.steps.length - 1);
    scrub.disabled = play.disabled = zoomBtn.disabled = false;
    const sigma = `2σ ${fmtM(2 * last.summary.sigma_major_m)}`;
    liveMsg.textContent = `${final ? "Stopped" : "Tracking"}: ${plural(pts.length - 1, "step")} · ` + (last.converged
      ? `located (${sigma})`
      : last.modes.length > 1
        ? `not located yet: ${last.modes.length} places fit the steps so far, up to ${fmtM(last.spread_m)} apart (the likeliest holds ${Math.round(100 * last.modes[0].mass)} %)`
        : `not located yet: one place holds ${Math.round(100 * last.modes[0].mass)} %, but it is ${sigma} across`);
    liveMsg.dataset.steps = String(pts.length - 1);
    liveMsg.dataset.converged = String(last.converged);
    setStep(track.steps.length - 1);
  }

  meBtn.addEventListener("click", async () => {
    if (!fp || live) return;
    const denied = await askMotionPermission(); // first: iOS asks only inside the tap
    if (denied) return void (liveMsg.textContent = denied);
    const start = parseStart(startField.value);
    if (startField.value.trim() && !start) return void (liveMsg.textContent = "Start: give x,y in metres, or tap the map.");
    meBtn.disabled = true;
    liveMsg.textContent = "Loading the model…";
    try {
      const model = await floorModel(fp.id);
      if (!alive) return;
      const session = new LiveSession(model, { start });
      stop();
      let got = false;
      const stopSensors = listenSensors({
        motion: (t, ax, ay, az) => {
          session.steps.addMotion(t, ax, ay, az);
          if (!got) (got = true), (liveMsg.textContent = "Walk: steps appear as you go.");
          if (session.update().length) showLive();
        },
        heading: (t, rad) => session.steps.addHeading(t, rad),
        status: (text) => (liveMsg.dataset.source = text),
      });
      live = { session, stop: stopSensors };
      stopBtn.disabled = false;
      zoomed = start !== null; // a known start: follow the walk; else the whole floor, where the modes are
      zoomBtn.textContent = zoomed ? "Whole floor" : "Zoom to walk";
      showLive();
      liveMsg.textContent = "Waiting for the motion sensors… hold the phone flat in front of you and walk.";
    } catch (err) {
      meBtn.disabled = false;
      liveMsg.textContent = `Cannot track: ${describeError(err)}`;
    }
  });

  stopBtn.addEventListener("click", () => {
    if (!live) return;
    live.session.update(true);
    showLive(true);
    stopLive();
  });

  (async () => {
    try {
      fp = await mapsApi.getFloor(id);
    } catch (err) {
      title.textContent = "Floor plan";
      meta.textContent = describeError(err);
      return;
    }
    if (!alive) return;
    title.textContent = fp.name;
    meta.replaceChildren(
      `${fp.width_m.toFixed(1)} × ${fp.height_m.toFixed(1)} m · ${fp.cell_m} m cells · ${fp.n_vertices ?? "–"} vertices · model ${fp.status}`,
      fp.status === "ready" ? h("span", {}, " · ", h("a", { href: mapsApi.modelUrl(fp.id), download: `floorplan-${fp.id}.npz`, "data-testid": "model-download" }, `download model (${kib(fp.model_bytes)})`)) : "",
    );
    trackBtn.disabled = fp.status !== "ready";
    if (fp.status === "ready") {
      // The model now, so that tracking starts at once and works offline from here on.
      void floorModel(fp.id).catch(() => undefined);
      keepForOffline(["/api/v1/auth/me", `/api/v1/floorplans/${fp.id}`, mapsApi.imageUrl(fp.id), mapsApi.modelUrl(fp.id)]);
    }
    if (fp.status !== "ready") msg.textContent = fp.status === "failed" ? `The model failed: ${fp.error}` : "The model is being built; reload in a moment.";
    void floorMap.show(fp, fp.has_image ? mapsApi.imageUrl(fp.id) : null);
    if (fp.has_image) {
      image = new Image();
      image.onload = () => {
        canvas.dataset.image = "loaded";
        draw();
      };
      image.src = mapsApi.imageUrl(fp.id);
    }
    draw();
  })();
  return () => {
    alive = false;
    stop();
    stopLive();
    floorMap.remove();
  };
}

/** A live session's modes: a circle at each mode's mean, labelled with its share of the mass. */
function drawModes(c: CanvasRenderingContext2D, v: View, modes: Mode[]) {
  c.font = "12px system-ui, sans-serif";
  for (const m of modes.slice(0, 12)) {
    const [x, y] = toPx(v, m.x, m.y);
    c.beginPath();
    c.arc(x, y, Math.max(5 * v.scale, 4), 0, 2 * Math.PI);
    c.fillStyle = `rgba(217,119,6,${(0.15 + 0.6 * m.mass).toFixed(2)})`;
    c.fill();
    c.strokeStyle = "#b45309";
    c.lineWidth = 1;
    c.stroke();
    if (m.mass >= 0.05) {
      c.fillStyle = "#78350f";
      c.fillText(`${Math.round(100 * m.mass)} %`, x + 6, y - 6);
    }
  }
}
