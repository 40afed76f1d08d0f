/**
 * Calls of the map-matching API (floor plans, walks, suggestions) and job polling, over the
 * typed client generated from the server's OpenAPI spec. Uploads are multipart: the
 * FormData goes through as is (the browser sets the boundary).
 */
import { type Schemas, client, unwrap } from "../api/client";

export type FloorPlan = Schemas["FloorPlanPublic"];

/** One step of a tracked walk (the spec leaves `WalkTrack.steps` items open: this is their shape). */
export interface WalkStep {
  i: number;
  t_ms: number;
  x_m: number;
  y_m: number;
  dr_x_m: number;
  dr_y_m: number;
  sigma_major_m: number;
  sigma_minor_m: number;
  angle_deg: number;
  /** The posterior has converged on one place (posefix.mapmatch.modes: one mode holds ≥ 95 %, 1σ ≤ 5 m): the ellipse is a fix. */
  converged?: boolean;
  /** Places the walker may be (modes holding ≥ 1 % each) and the farthest one's distance from the main one. */
  n_modes?: number;
  mode_spread_m?: number;
}

export interface WaypointError {
  t_ms: number;
  x_m: number;
  y_m: number;
  error_m: number;
  dr_error_m: number;
  given_start: boolean;
}

/** `Schemas["WalkTrack"]` with its open members spelled out. */
export interface WalkTrack {
  steps: WalkStep[];
  errors: { n: number; mean_m: number | null; median_m: number | null; p95_m: number | null; max_m: number | null; dr_mean_m?: number; skip_first: boolean; waypoints: WaypointError[] };
  walk: { file: string; n_steps: number; start: string; track_ms: number; ms_per_step: number; converged_share?: number; converged_at_end?: boolean; wifi?: WalkWifi };
}
/** What a walk's WiFi contributed (the server's `walk.wifi`): survey fixes used, or why none. */
export interface WalkWifi {
  fingerprints: string | null;
  fixes: number;
  used: boolean;
  note: string;
  walk_corr: number | null;
  robust: boolean | null;
}
export type JobView = Schemas["JobPublic"];

const fid = (id: number) => ({ params: { path: { floorplan_id: id } } });
// The generated multipart body types describe fields; a FormData carries them.
const form = (fd: FormData) => ({ body: fd as never, bodySerializer: (b: unknown) => b as FormData });

export const mapsApi = {
  listFloors: () => unwrap(client.GET("/api/v1/floorplans")),
  getFloor: (id: number) => unwrap(client.GET("/api/v1/floorplans/{floorplan_id}", fid(id))),
  uploadFloor: (fd: FormData) => unwrap(client.POST("/api/v1/floorplans", form(fd))),
  deleteFloor: (id: number) => unwrap(client.DELETE("/api/v1/floorplans/{floorplan_id}", fid(id))),
  trackWalk: async (id: number, fd: FormData): Promise<WalkTrack> =>
    (await unwrap(client.POST("/api/v1/floorplans/{floorplan_id}/walks", { ...fid(id), ...form(fd) }))) as unknown as WalkTrack,
  imageUrl: (id: number) => `/api/v1/floorplans/${id}/image`,
  modelUrl: (id: number) => `/api/v1/floorplans/${id}/model`,
  /** Start matching a run (the answer is a job; its result is the suggestions). */
  suggestions: async (runId: string): Promise<Schemas["SuggestionsJob"]> => {
    const r = await unwrap(client.POST("/api/v1/runs/{run_id}/suggestions", { params: { path: { run_id: Number(runId) } }, body: {} }));
    if (!("job_id" in r)) throw new Error("The server answered suggestions without a job.");
    return r;
  },
  getJob: (id: number) => unwrap(client.GET("/api/v1/jobs/{job_id}", { params: { path: { job_id: id } } })),
};

/** Poll a job until it has finished; its result, or an Error with the job's reason. */
export async function jobResult(jobId: number, onProgress: (fraction: number, message: string | null) => void, alive: () => boolean = () => true, pollMs = 400, timeoutMs = 120_000): Promise<unknown> {
  const t0 = Date.now();
  for (;;) {
    const job = await mapsApi.getJob(jobId);
    if (job.status === "succeeded") return job.result;
    if (job.status === "dead") throw new Error((job.last_error ?? "the job failed").split("\n")[0]);
    if (!alive()) throw new Error("cancelled");
    if (Date.now() - t0 > timeoutMs) throw new Error("the job is taking long; try again later");
    onProgress(job.progress, job.message ?? null);
    await new Promise((r) => setTimeout(r, pollMs));
  }
}
