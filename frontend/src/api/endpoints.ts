/** One function per API route the front end uses. */
import type { Edits, LonLat, RunDoc } from "../state/types";
import { type Schemas, client, request, unwrap } from "./client";
import { docFromKeyframes, editsBody } from "./convert";

export type UserPublic = Schemas["UserPublic"];
export type RunSummary = Schemas["RunPublic"];
export type TileSource = Schemas["TileSourcePublic"];
export type ImagePublic = Schemas["ImagePublic"];

export interface PreviewResult {
  positions: LonLat[];
  solverTimeS: number | null;
  refusals: { index: number; reason: string; message: string }[];
  raw: Record<string, unknown>;
}

export const api = {
  login: (username: string, password: string) => unwrap(client.POST("/api/v1/auth/login", { body: { username, password } })),
  logout: () => unwrap(client.POST("/api/v1/auth/logout", {})),
  me: () => unwrap(client.GET("/api/v1/auth/me")),

  listRuns: (query: { limit?: number; offset?: number; name?: string; status?: string } = {}) =>
    unwrap(client.GET("/api/v1/runs", { params: { query: query as never } })),
  getRun: (id: string) => unwrap(client.GET("/api/v1/runs/{run_id}", { params: { path: { run_id: Number(id) } } })),
  runImages: (id: string) => unwrap(client.GET("/api/v1/runs/{run_id}/images", { params: { path: { run_id: Number(id) } } })),

  async loadDoc(id: string, revision?: number): Promise<RunDoc> {
    const run = await api.getRun(id);
    const fc = await unwrap(
      client.GET("/api/v1/runs/{run_id}/keyframes", { params: { path: { run_id: Number(id) }, query: revision === undefined ? {} : { revision } }, parseAs: "json" }),
    );
    return docFromKeyframes(id, run.name, fc as Record<string, unknown>);
  },

  async preview(id: string, baseRevision: number, edits: Edits, signal?: AbortSignal): Promise<PreviewResult> {
    const b = editsBody(edits);
    const raw = await request<Record<string, unknown>>("POST", `/runs/${encodeURIComponent(id)}/preview`, { base_revision: baseRevision, moves: b.moves, deleted: b.deleted }, {}, signal);
    const solver = (raw.solver ?? {}) as Record<string, unknown>;
    const t = solver.time_s;
    return {
      positions: ((raw.positions ?? []) as number[][]).map((p) => [p[0], p[1]] as LonLat),
      solverTimeS: typeof t === "number" ? t : null,
      refusals: (raw.refusals ?? []) as PreviewResult["refusals"],
      raw,
    };
  },

  submitEdits: (id: string, baseRevision: number, edits: Edits, comment: string) =>
    request<{ batch_id: number | string; job_id: number | string }>("POST", `/runs/${encodeURIComponent(id)}/edits`, { base_revision: baseRevision, ...editsBody(edits), comment }, { "If-Match": `"${baseRevision}"` }),

  getJob: (id: string | number) => unwrap(client.GET("/api/v1/jobs/{job_id}", { params: { path: { job_id: Number(id) } } })),
  listRevisions: (id: string) => request<unknown>("GET", `/runs/${encodeURIComponent(id)}/revisions`),

  listTileSources: () => unwrap(client.GET("/api/v1/tile-sources")),
  addTileSource: (body: Schemas["TileSourceCreate"]) => unwrap(client.POST("/api/v1/tile-sources", { body })),
  deleteTileSource: (ref: string) => unwrap(client.DELETE("/api/v1/tile-sources/{ref}", { params: { path: { ref } } })),
  styleUrl: () => `${location.origin}/api/v1/map/style.json`,
  imageUrl: (id: string) => `/api/v1/images/${encodeURIComponent(id)}`,
  thumbnailUrl: (id: string) => `/api/v1/images/${encodeURIComponent(id)}/thumbnail`,
};

/** Upload a run with upload progress (XHR: fetch has no upload progress events). */
export function uploadRun(form: FormData, onProgress: (fraction: number) => void): Promise<RunSummary> {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", "/api/v1/runs");
    xhr.withCredentials = true;
    xhr.setRequestHeader("Accept", "application/json");
    xhr.upload.onprogress = (e) => e.lengthComputable && onProgress(e.loaded / e.total);
    xhr.onerror = () => reject(new Error("Cannot reach the server: the upload did not finish."));
    xhr.onload = () => {
      let data: unknown = xhr.responseText;
      try {
        data = JSON.parse(xhr.responseText);
      } catch {
        /* text */
      }
      if (xhr.status >= 200 && xhr.status < 300) resolve(data as RunSummary);
      else {
        const b = (data && typeof data === "object" ? data : {}) as Record<string, unknown>;
        reject(new Error(`${xhr.status}: ${typeof b.detail === "string" ? b.detail : JSON.stringify(b.detail ?? data)}`));
      }
    };
    xhr.send(form);
  });
}
