/** One function per API route the front end uses. */
import type { Drift, Edits, LonLat, Refusal, RunDoc } from "../state/types";
import { type Schemas, client, unwrap } from "./client";
import { baseMovesFrom, docFromKeyframes, driftFrom, editsBody } from "./convert";

export type UserPublic = Schemas["UserPublic"];
export type RunSummary = Schemas["RunPublic"];
export type TileSource = Schemas["TileSourcePublic"];
export type ImagePublic = Schemas["ImagePublic"];
export type RevisionPublic = Schemas["RevisionPublic"];
export type UserActivity = Schemas["UserActivity"];

export interface PreviewResult {
  positions: LonLat[];
  solverTimeS: number | null;
  refusals: Refusal[];
  flags: Refusal[];
  drift: Drift | null;
}

export const api = {
  login: (username: string, password: string) => unwrap(client.POST("/api/v1/auth/login", { body: { username, password } })),
  logout: () => unwrap(client.POST("/api/v1/auth/logout", {})),
  me: () => unwrap(client.GET("/api/v1/auth/me")),

  uploadFormats: () => unwrap(client.GET("/api/v1/upload-formats")),
  listRuns: (query: { limit?: number; offset?: number; name?: string; status?: string } = {}) =>
    unwrap(client.GET("/api/v1/runs", { params: { query: query as never } })),
  getRun: (id: string) => unwrap(client.GET("/api/v1/runs/{run_id}", { params: { path: { run_id: Number(id) } } })),
  runImages: (id: string) => unwrap(client.GET("/api/v1/runs/{run_id}/images", { params: { path: { run_id: Number(id) } } })),

  async loadDoc(id: string, revision?: number): Promise<RunDoc> {
    const run = await api.getRun(id);
    const fc = await unwrap(
      client.GET("/api/v1/runs/{run_id}/keyframes", { params: { path: { run_id: Number(id) }, query: revision === undefined ? {} : { revision } }, parseAs: "json" }),
    );
    const doc = docFromKeyframes(id, run.name, fc as Record<string, unknown>);
    if (!doc.keyframes.some((k) => k.edited)) return doc;
    // The rules judge order against where earlier moves put their keyframes.
    const rev = await unwrap(client.GET("/api/v1/runs/{run_id}/revisions/{number}", { params: { path: { run_id: Number(id), number: doc.revision } } }));
    return { ...doc, baseMoves: baseMovesFrom(rev.edit_set) };
  },

  async preview(id: string, baseRevision: number, edits: Edits, signal?: AbortSignal): Promise<PreviewResult> {
    const b = editsBody(edits);
    const raw = await unwrap(
      client.POST("/api/v1/runs/{run_id}/preview", { params: { path: { run_id: Number(id) } }, body: { base_revision: baseRevision, moves: b.moves, deleted: b.deleted }, signal }),
    );
    const t = raw.solver?.time_s;
    return {
      positions: raw.positions.map((p) => [p[0], p[1]] as LonLat),
      solverTimeS: typeof t === "number" ? t : raw.time_ms / 1000,
      refusals: raw.refusals,
      flags: raw.flags,
      drift: driftFrom(raw.drift),
    };
  },

  submitEdits: (id: string, baseRevision: number, edits: Edits, comment: string) =>
    unwrap(
      client.POST("/api/v1/runs/{run_id}/edits", {
        params: { path: { run_id: Number(id) }, header: { "If-Match": `"${baseRevision}"` } },
        body: { base_revision: baseRevision, ...editsBody(edits), comment: comment || null },
      }),
    ),

  retryBatch: (id: string, batchId: number) =>
    unwrap(client.POST("/api/v1/runs/{run_id}/batches/{batch_id}/retry", { params: { path: { run_id: Number(id), batch_id: batchId } } })),
  discardBatch: (id: string, batchId: number) =>
    unwrap(client.POST("/api/v1/runs/{run_id}/batches/{batch_id}/discard", { params: { path: { run_id: Number(id), batch_id: batchId } } })),

  getJob: (id: string | number) => unwrap(client.GET("/api/v1/jobs/{job_id}", { params: { path: { job_id: Number(id) } } })),
  listRevisions: (id: string) => unwrap(client.GET("/api/v1/runs/{run_id}/revisions", { params: { path: { run_id: Number(id) } } })),
  diff: (id: string, from: number, to: number) =>
    unwrap(client.GET("/api/v1/runs/{run_id}/diff", { params: { path: { run_id: Number(id) }, query: { from, to } } })),
  revert: (id: string, toRevision: number, baseRevision: number, comment: string) =>
    unwrap(client.POST("/api/v1/runs/{run_id}/revert", { params: { path: { run_id: Number(id) } }, body: { to_revision: toRevision, base_revision: baseRevision, comment: comment || null } })),
  listUsers: () => unwrap(client.GET("/api/v1/users", { params: { query: { limit: 500 } } })),
  userActivity: (userId: number) => unwrap(client.GET("/api/v1/users/{user_id}/activity", { params: { path: { user_id: userId } } })),

  listTileSources: () => unwrap(client.GET("/api/v1/tile-sources")),
  addTileSource: (body: Schemas["TileSourceCreate"]) => unwrap(client.POST("/api/v1/tile-sources", { body })),
  deleteTileSource: (ref: string) => unwrap(client.DELETE("/api/v1/tile-sources/{ref}", { params: { path: { ref } } })),
  /** Server-sent events of one run (revision.ready, ...), for an EventSource. */
  runEventsUrl: (runId: string, maxS = 3600) => `/api/v1/events?run_id=${encodeURIComponent(runId)}&max_s=${maxS}`,
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
