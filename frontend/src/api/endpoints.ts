/** One function per API route the front end uses. */
import type { Edits, LonLat, RunDoc } from "../state/types";
import { request } from "./client";
import { docFromKeyframes, editsBody } from "./convert";

export interface UserPublic {
  id: number | string;
  username: string;
  role: string;
}

export interface RunSummary {
  id: number | string;
  name: string;
  status: string;
  revision?: number;
  created_at?: string;
  updated_at?: string;
  n_keyframes?: number;
  [k: string]: unknown;
}

export interface TileSource {
  id: number;
  name: string;
  title: string;
  kind: string;
  attribution: string;
  min_zoom: number;
  max_zoom: number;
  format: string;
  origin: string;
  tile_url: string;
}

export interface PreviewResult {
  positions: LonLat[];
  solverTimeS: number | null;
  refusals: { index: number; reason: string; message: string }[];
  raw: Record<string, unknown>;
}

export const api = {
  login: (username: string, password: string) => request<UserPublic>("POST", "/auth/login", { username, password }),
  logout: () => request<unknown>("POST", "/auth/logout", {}),
  me: () => request<UserPublic>("GET", "/auth/me"),

  listRuns: (params: Record<string, string | number | undefined> = {}) => {
    const q = new URLSearchParams();
    for (const [k, v] of Object.entries(params)) if (v !== undefined && v !== "") q.set(k, String(v));
    const qs = q.toString();
    return request<{ items: RunSummary[]; total: number }>("GET", `/runs${qs ? `?${qs}` : ""}`);
  },
  getRun: (id: string) => request<RunSummary>("GET", `/runs/${encodeURIComponent(id)}`),

  async loadDoc(id: string, revision?: number): Promise<RunDoc> {
    const run = await api.getRun(id);
    const fc = await request<Record<string, unknown>>("GET", `/runs/${encodeURIComponent(id)}/keyframes${revision !== undefined ? `?revision=${revision}` : ""}`);
    return docFromKeyframes(id, String(run.name ?? id), fc);
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

  getJob: (id: string | number) => request<{ status: string; progress?: number; error?: string | null; [k: string]: unknown }>("GET", `/jobs/${encodeURIComponent(String(id))}`),
  listRevisions: (id: string) => request<unknown>("GET", `/runs/${encodeURIComponent(id)}/revisions`),

  listTileSources: () => request<{ items: TileSource[]; total: number }>("GET", "/tile-sources"),
  addTileSource: (body: Record<string, unknown>) => request<TileSource>("POST", "/tile-sources", body),
  deleteTileSource: (id: number | string) => request<unknown>("DELETE", `/tile-sources/${encodeURIComponent(String(id))}`),
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
