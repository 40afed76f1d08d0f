/**
 * Calls of the tasks API (/api/v1/tasks, /assignments, /review, /operators). Plain fetch with
 * the app's ApiError, so pages show the server's reason in words.
 */
import { ApiError, apiErrorFrom, networkError } from "../api/errors";

export type Json = Record<string, unknown>;

export interface TaskBrief { id: number; title: string; instructions: string; reward_cents: number; currency: string; rules: Json | null }
export interface Assignment {
  id: number; task_id: number; run_id: number; status: string; operator_id: number | null; base_revision: number | null;
  leased_at: string | null; lease_expires_at: string | null; lease_remaining_s: number | null; submitted_at: string | null;
  comment: string | null; feedback: string | null; reviewed_at: string | null; auto_approve_at: string | null; task: TaskBrief;
}
export interface Ineligible { task_id: number; title: string; reasons: string[] }
export interface NextResponse { assignment: Assignment | null; message: string; ineligible: Ineligible[] }
export interface TaskRun { id: number; run_id: number; wanted: number; status: string; conflicts: Json[] | null; merged_revision: number | null; counts: Record<string, number> }
export interface Task {
  id: number; title: string; instructions: string; status: string; priority: number; assignments_per_run: number;
  reward_cents: number; currency: string; counts: Record<string, number>; runs: TaskRun[]; expires_at: string;
  requirements: Json[]; conflict_policy: string;
}
export interface Submission {
  assignment_id: number; operator_id: number | null; operator: string | null; status: string; submitted_at: string | null;
  comment: string | null; moves: [number, number, number, number | null][]; deleted: number[];
  positions: [number, number][] | null; consensus_error_m: number | null;
}
export interface ReviewView {
  task_run_id: number; task_id: number; run_id: number; status: string; reported: [number, number][];
  consensus: [number, number][] | null; disagreement_m: number[] | null; conflicts: Json[] | null;
  submissions: Submission[]; merged_revision: number | null;
}
export interface ReviewItem { task_run_id: number; task_id: number; task_title: string; run_id: number; status: string; submitted: number; conflicts: number }
export interface OperatorStats {
  user_id: number; username: string; submitted: number; approved: number; rejected: number; returned: number; expired: number;
  accuracy_m: number | null; gold_scored: number; agreement_m: number | null; throughput_per_h: number | null;
  mean_work_s: number | null; test_status: string; home_area: Json | null; qualifications: { name: string; value: number }[];
}

async function call<T>(method: string, path: string, body?: unknown): Promise<T> {
  let r: Response;
  try {
    r = await fetch(`/api/v1${path}`, {
      method, credentials: "same-origin",
      headers: body === undefined ? { Accept: "application/json" } : { Accept: "application/json", "Content-Type": "application/json" },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch (err) {
    throw networkError(err);
  }
  if (r.status === 204) return undefined as T;
  let data: unknown = null;
  const text = await r.text();
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    data = text;
  }
  if (!r.ok) throw apiErrorFrom(r.status, data, r.statusText);
  return data as T;
}

export const tasksApi = {
  next: () => call<NextResponse>("POST", "/tasks/next"),
  mine: (status?: string) => call<Assignment[]>("GET", `/assignments/mine${status ? `?status=${status}` : ""}`),
  assignment: (id: number) => call<Assignment>("GET", `/assignments/${id}`),
  extend: (id: number) => call<Assignment>("POST", `/assignments/${id}/extend`),
  giveBack: (id: number) => call<Assignment>("POST", `/assignments/${id}/return`),
  submit: (id: number, body: Json) => call<{ assignment: Assignment; flags: Json[] }>("POST", `/assignments/${id}/submit`, body),
  create: (body: Json) => call<Task>("POST", "/tasks", body),
  list: () => call<{ items: Task[]; total: number }>("GET", "/tasks?limit=200"),
  get: (id: number) => call<Task>("GET", `/tasks/${id}`),
  cancel: (id: number) => call<Task>("POST", `/tasks/${id}/cancel`),
  reviewQueue: () => call<ReviewItem[]>("GET", "/review/queue"),
  reviewView: (taskRunId: number) => call<ReviewView>("GET", `/task-runs/${taskRunId}/review`),
  review: (assignmentId: number, decision: "approve" | "reject", feedback: string) =>
    call<Assignment>("POST", `/assignments/${assignmentId}/review`, { decision, feedback: feedback || null }),
  operators: () => call<OperatorStats[]>("GET", "/operators"),
  me: () => call<OperatorStats>("GET", "/operators/me"),
  grant: (userId: number, name: string, value: number) => call<Json>("POST", `/operators/${userId}/qualifications`, { name, value }),
  revoke: (userId: number, name: string) => call<void>("DELETE", `/operators/${userId}/qualifications/${encodeURIComponent(name)}`),
  setHome: (userId: number | "me", body: Json) => call<OperatorStats>("PUT", `/operators/${userId}/home-area`, body),
  runs: () => call<{ items: { id: number; name: string; status: string; bbox: number[]; n_keyframes: number }[] }>("GET", "/runs?limit=500"),
};

export { ApiError };
