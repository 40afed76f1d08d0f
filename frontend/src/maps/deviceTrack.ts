/**
 * The floor page's bridge to the browser tracker: the model download (once per floor; the
 * service worker keeps it for offline use) and the tracker's output in the shape the page
 * draws (`WalkTrack`, the same as the server's walk answer).
 */
import { networkError } from "../api/errors";
import type { LivePoint } from "../tracker/live";
import { type TrackerModel, loadModel } from "../tracker/model";
import { type Walk, wifiScans } from "../tracker/sensors";
import { type FingerprintMap, predictScan } from "../tracker/fingerprints";
import type { WalkRun } from "../tracker/tracker";
import { waypointErrors } from "../tracker/evaluate";
import { type WalkStep, type WalkTrack, type WalkWifi, mapsApi } from "./api";

const models = new Map<number, Promise<TrackerModel>>();

/** The floor's model, downloaded once per page load. */
export function floorModel(id: number): Promise<TrackerModel> {
  let p = models.get(id);
  if (!p) {
    p = (async () => {
      let r: Response;
      try {
        r = await fetch(mapsApi.modelUrl(id), { credentials: "same-origin" });
      } catch (err) {
        throw networkError(err);
      }
      if (!r.ok) throw new Error(`the model could not be downloaded (HTTP ${r.status})`);
      return loadModel(new Uint8Array(await r.arrayBuffer()), `floorplan-${id}.npz`);
    })();
    p.catch(() => models.delete(id));
    models.set(id, p);
  }
  return p;
}

const r3 = (v: number) => Math.round(v * 1000) / 1000;

function mean(v: number[]): number | null {
  return v.length ? v.reduce((a, b) => a + b, 0) / v.length : null;
}

/** What a walk's WiFi gave the browser tracker, as the server reports it (`walk.wifi`): the
 * scans the survey placed, or why none (an f3 the survey could not calibrate). */
export function walkWifi(fp: FingerprintMap | null, walk: Walk, name: string | null): WalkWifi {
  if (!fp) return { fingerprints: null, fixes: 0, used: false, note: "no fingerprint file given", walk_corr: null, robust: null };
  const fixes = fp.f3Calibrated ? wifiScans(walk.wifi).filter((s) => predictScan(fp, s.rssi) !== null).length : 0;
  const note = !fp.f3Calibrated ? fp.f3Note : fixes ? "" : "no scan of this walk matched the survey";
  return { fingerprints: name, fixes, used: fixes > 0, note, walk_corr: Math.round(fp.walkCorr * 1000) / 1000, robust: fp.robust };
}

/** A walk tracked in the browser, as the page's track (live positions, errors at the waypoints). */
export function walkTrackFromRun(run: WalkRun, walk: Walk, file: string, skipFirst: boolean, wifi?: WalkWifi): WalkTrack {
  const steps: WalkStep[] = Array.from(run.t_ms, (t, i) => ({
    i, t_ms: t, x_m: r3(run.x[i]), y_m: r3(run.y[i]), dr_x_m: r3(run.dr_x[i]), dr_y_m: r3(run.dr_y[i]),
    sigma_major_m: r3(run.sigma_major_m[i]), sigma_minor_m: r3(run.sigma_minor_m[i]), angle_deg: Math.round(run.angle_deg[i] * 10) / 10,
    converged: run.modes[i].converged, n_modes: run.modes[i].modes.length, mode_spread_m: Math.round(run.modes[i].spread_m * 10) / 10,
  }));
  const convergedShare = run.modes.filter((m) => m.converged).length / run.modes.length;
  const wp = walk.waypoints;
  const err = waypointErrors(run.t_ms, run.x, run.y, wp);
  const errDr = waypointErrors(run.t_ms, run.dr_x, run.dr_y, wp);
  const scored = skipFirst ? err.slice(1) : err;
  const scoredDr = skipFirst ? errDr.slice(1) : errDr;
  const sorted = [...scored].sort((a, b) => a - b);
  return {
    steps,
    errors: {
      n: scored.length, mean_m: mean(scored), median_m: sorted.length ? sorted[sorted.length >> 1] : null, p95_m: null,
      max_m: sorted.length ? sorted[sorted.length - 1] : null, dr_mean_m: mean(scoredDr) ?? undefined, skip_first: skipFirst,
      waypoints: wp.map((w, j) => ({ t_ms: w.t_ms, x_m: w.x_m, y_m: w.y_m, error_m: err[j], dr_error_m: errDr[j], given_start: skipFirst && j === 0 })),
    },
    walk: {
      file, n_steps: run.t_ms.length - 1, start: skipFirst ? "first_waypoint" : "unknown", track_ms: run.ms_per_step * (run.t_ms.length - 1), ms_per_step: run.ms_per_step,
      converged_share: Math.round(convergedShare * 1000) / 1000, converged_at_end: run.modes[run.modes.length - 1].converged,
      ...(wifi ? { wifi } : {}),
    },
  };
}

/** The live session's points as the page's track (no waypoints). */
export function liveTrack(points: LivePoint[]): WalkTrack {
  return {
    steps: points.map((p, i) => ({
      i, t_ms: p.t_ms, x_m: p.summary.x, y_m: p.summary.y, dr_x_m: p.dr[0], dr_y_m: p.dr[1],
      sigma_major_m: p.summary.sigma_major_m, sigma_minor_m: p.summary.sigma_minor_m, angle_deg: p.summary.angle_deg,
      converged: p.converged, n_modes: p.modes.length, mode_spread_m: p.spread_m,
    })),
    errors: { n: 0, mean_m: null, median_m: null, p95_m: null, max_m: null, skip_first: false, waypoints: [] },
    walk: { file: "live", n_steps: points.length - 1, start: "live", track_ms: 0, ms_per_step: 0 },
  };
}
