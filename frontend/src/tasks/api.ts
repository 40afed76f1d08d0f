/**
 * Calls of the tasks API (/api/v1/tasks, /assignments, /review, /operators) over the typed
 * client generated from the server's OpenAPI spec; errors are the app's ApiError, so pages
 * show the server's reason in words.
 */
import { type Schemas, client, unwrap } from "../api/client";

export type Json = Record<string, unknown>;
export type Assignment = Schemas["AssignmentPublic"];
export type NextResponse = Schemas["NextResponse"];
export type Task = Schemas["TaskPublic"];
export type TaskRun = Schemas["TaskRunPublic"];
export type Submission = Schemas["SubmissionView"];
export type ReviewView = Schemas["ReviewView"];
export type ReviewItem = Schemas["ReviewQueueItem"];
export type OperatorStats = Schemas["OperatorStats"];
export type TaskCreate = Schemas["TaskCreate"];
export type SubmitIn = Schemas["SubmitIn"];
export type HomeArea = Schemas["HomeAreaIn"];

const aid = (id: number) => ({ params: { path: { assignment_id: id } } });
const tid = (id: number) => ({ params: { path: { task_id: id } } });

export const tasksApi = {
  next: () => unwrap(client.POST("/api/v1/tasks/next", {})),
  mine: (status?: Schemas["AssignmentStatus"]) =>
    unwrap(client.GET("/api/v1/assignments/mine", { params: { query: status ? { status: [status] } : {} } })),
  assignment: (id: number) => unwrap(client.GET("/api/v1/assignments/{assignment_id}", aid(id))),
  extend: (id: number) => unwrap(client.POST("/api/v1/assignments/{assignment_id}/extend", aid(id))),
  giveBack: (id: number) => unwrap(client.POST("/api/v1/assignments/{assignment_id}/return", aid(id))),
  submit: (id: number, body: SubmitIn) => unwrap(client.POST("/api/v1/assignments/{assignment_id}/submit", { ...aid(id), body })),
  create: (body: TaskCreate) => unwrap(client.POST("/api/v1/tasks", { body })),
  list: () => unwrap(client.GET("/api/v1/tasks", { params: { query: { limit: 200 } } })),
  get: (id: number) => unwrap(client.GET("/api/v1/tasks/{task_id}", tid(id))),
  cancel: (id: number) => unwrap(client.POST("/api/v1/tasks/{task_id}/cancel", tid(id))),
  reviewQueue: () => unwrap(client.GET("/api/v1/review/queue")),
  reviewView: (taskRunId: number) => unwrap(client.GET("/api/v1/task-runs/{task_run_id}/review", { params: { path: { task_run_id: taskRunId } } })),
  mergeAgain: (taskRunId: number) =>
    unwrap(client.POST("/api/v1/task-runs/{task_run_id}/merge", { params: { path: { task_run_id: taskRunId } } })),
  review: (assignmentId: number, decision: "approve" | "reject", feedback: string) =>
    unwrap(client.POST("/api/v1/assignments/{assignment_id}/review", { ...aid(assignmentId), body: { decision, feedback: feedback || null } })),
  operators: () => unwrap(client.GET("/api/v1/operators")),
  me: () => unwrap(client.GET("/api/v1/operators/me")),
  grant: (userId: number, name: string, value: number) =>
    unwrap(client.POST("/api/v1/operators/{user_id}/qualifications", { params: { path: { user_id: userId } }, body: { name, value } })),
  revoke: (userId: number, name: string) =>
    unwrap(client.DELETE("/api/v1/operators/{user_id}/qualifications/{name}", { params: { path: { user_id: userId, name } } })),
  setHome: (userId: number | "me", body: HomeArea) =>
    userId === "me"
      ? unwrap(client.PUT("/api/v1/operators/me/home-area", { body }))
      : unwrap(client.PUT("/api/v1/operators/{user_id}/home-area", { params: { path: { user_id: userId } }, body })),
  runs: () => unwrap(client.GET("/api/v1/runs", { params: { query: { limit: 500 } } })),
};
