/**
 * Calls of the map-matching API (floor plans, walks, suggestions). Plain fetch: the routes
 * are newer than the generated client's schema; errors become the same ApiError.
 */
import { apiErrorFrom, networkError } from "../api/errors";

export interface FloorPlan {
  id: number;
  name: string;
  source: string;
  status: "queued" | "ready" | "failed" | string;
  cell_m: number;
  width_m: number;
  height_m: number;
  georef: number[] | null;
  has_image: boolean;
  n_vertices: number | null;
  model_bytes: number | null;
  build_s: number | null;
  error: string | null;
  job_id: number | null;
  created_at: string;
}

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
}

export interface WaypointError {
  t_ms: number;
  x_m: number;
  y_m: number;
  error_m: number;
  dr_error_m: number;
  given_start: boolean;
}

export interface WalkTrack {
  steps: WalkStep[];
  errors: { n: number; mean_m: number | null; median_m: number | null; p95_m: number | null; max_m: number | null; dr_mean_m?: number; skip_first: boolean; waypoints: WaypointError[] };
  walk: { file: string; n_steps: number; start: string; track_ms: number; ms_per_step: number };
}

async function call<T>(method: string, url: string, body?: BodyInit | object): Promise<T> {
  const init: RequestInit = { method, credentials: "same-origin", headers: { Accept: "application/json" } };
  if (body instanceof FormData) init.body = body;
  else if (body !== undefined) {
    init.body = JSON.stringify(body);
    (init.headers as Record<string, string>)["Content-Type"] = "application/json";
  }
  let r: Response;
  try {
    r = await fetch(url, init);
  } catch (err) {
    throw networkError(err);
  }
  const text = await r.text();
  let data: unknown = text;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    /* not JSON */
  }
  if (!r.ok) throw apiErrorFrom(r.status, data, r.statusText);
  return data as T;
}

export const mapsApi = {
  listFloors: () => call<{ items: FloorPlan[]; total: number }>("GET", "/api/v1/floorplans"),
  getFloor: (id: number) => call<FloorPlan>("GET", `/api/v1/floorplans/${id}`),
  uploadFloor: (form: FormData) => call<FloorPlan>("POST", "/api/v1/floorplans", form),
  deleteFloor: (id: number) => call<null>("DELETE", `/api/v1/floorplans/${id}`),
  trackWalk: (id: number, form: FormData) => call<WalkTrack>("POST", `/api/v1/floorplans/${id}/walks`, form),
  imageUrl: (id: number) => `/api/v1/floorplans/${id}/image`,
  modelUrl: (id: number) => `/api/v1/floorplans/${id}/model`,
  suggestions: (runId: string) => call<{ job_id: number; status: string; revision: number }>("POST", `/api/v1/runs/${encodeURIComponent(runId)}/suggestions`, {}),
  getJob: (id: number) => call<JobView>("GET", `/api/v1/jobs/${id}`),
};

export interface JobView {
  status: string;
  progress: number;
  message: string | null;
  last_error: string | null;
  result: unknown;
}

/** Poll a job until it has finished; its result, or an Error with the job's reason. */
export async function jobResult(jobId: number, onProgress: (fraction: number, message: string | null) => void, alive: () => boolean = () => true, pollMs = 400, timeoutMs = 120_000): Promise<unknown> {
  const t0 = Date.now();
  for (;;) {
    const job = await mapsApi.getJob(jobId);
    if (job.status === "succeeded") return job.result;
    if (job.status === "dead") throw new Error((job.last_error ?? "the job failed").split("\n")[0]);
    if (!alive()) throw new Error("cancelled");
    if (Date.now() - t0 > timeoutMs) throw new Error("the job is taking long; try again later");
    onProgress(job.progress, job.message);
    await new Promise((r) => setTimeout(r, pollMs));
  }
}
