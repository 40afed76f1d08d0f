/** The task pages' routes (#/tasks/...) and their links in the top bar. */
import type { UserPublic } from "../api/endpoints";
import type { AppContext } from "../ui/context";
import { h } from "../ui/dom";
import { renderTasksAdmin } from "./admin";
import { renderOperators } from "./operators";
import { renderReview, renderReviewQueue } from "./review";
import { renderAssignment, renderWork } from "./work";
import "./tasks.css";

export function tasksNav(u: UserPublic | null): HTMLElement[] {
  if (!u) return [];
  const links: HTMLElement[] = [];
  if (u.role !== "client") links.push(h("a", { href: "#/tasks/work" }, "Work"));
  if (u.role === "admin" || u.role === "client") links.push(h("a", { href: "#/tasks/admin" }, "Tasks"));
  if (u.role === "admin" || u.role === "reviewer") links.push(h("a", { href: "#/tasks/review" }, "Review"));
  if (u.role === "admin") links.push(h("a", { href: "#/tasks/operators" }, "Operators"));
  return links;
}

export function renderTasksRoute(path: string, main: HTMLElement, ctx: AppContext): (() => void) | void {
  let m = path.match(/^\/tasks\/work\/(\d+)/);
  if (m) return renderAssignment(main, ctx, Number(m[1]));
  m = path.match(/^\/tasks\/review\/(\d+)/);
  if (m) return renderReview(main, ctx, Number(m[1]));
  if (path.startsWith("/tasks/review")) return renderReviewQueue(main, ctx);
  if (path.startsWith("/tasks/admin")) return renderTasksAdmin(main, ctx);
  if (path.startsWith("/tasks/operators")) return renderOperators(main, ctx);
  return renderWork(main, ctx);
}
