/**
 * The application shell: a hash router (#/login, #/, #/runs/ID, #/admin/runs, #/admin/tiles),
 * the top bar, and the signed-in user. Pages render into the main area and return a
 * cleanup function.
 */
import { api } from "../api/endpoints";
import type { AppContext } from "./context";
import { ApiError } from "../api/errors";
import { renderAdminRuns } from "./adminRuns";
import { renderAdminPeople } from "./adminPeople";
import { renderAdminTiles } from "./adminTiles";
import { clear, h } from "./dom";
import { renderEditor } from "./editor/view";
import { installHelpOverlay, renderHelp } from "./help";
import { renderHome } from "./home";
import { renderLogin } from "./login";
import { renderTasksRoute, tasksNav } from "../tasks/routes";
import { renderFloorsRoute } from "../maps/floorPage";


type Cleanup = (() => void) | void;

export function startApp(root: HTMLElement): void {
  let cleanup: Cleanup;
  const header = h("header", { class: "topbar" });
  const main = h("main", { id: "main" });
  root.append(header, main);

  const ctx: AppContext = {
    user: null,
    setUser(u) {
      ctx.user = u;
      renderHeader();
    },
    navigate(hash) {
      if (location.hash === hash) route();
      else location.hash = hash;
    },
  };

  function renderHeader() {
    clear(header);
    const u = ctx.user;
    header.append(
      h("a", { class: "brand", href: "#/" }, "posefix"),
      h(
        "nav",
        { "aria-label": "Main" },
        u ? h("a", { href: "#/" }, "My runs") : null,
        u && u.role === "admin" ? h("a", { href: "#/admin/runs" }, "Runs (admin)") : null,
        u && u.role === "admin" ? h("a", { href: "#/admin/tiles" }, "Tile sources") : null,
        u && u.role === "admin" ? h("a", { href: "#/admin/people" }, "People") : null,
        ...tasksNav(u),
        u ? h("a", { href: "#/floors" }, "Floor plans") : null,
        h("a", { href: "#/help", "data-testid": "help-link", title: "Help and keyboard shortcuts (?)" }, "Help"),
      ),
      u
        ? h(
            "div",
            { class: "user" },
            h("span", { "data-testid": "whoami" }, `${u.username} (${u.role})`),
            h("button", {
              type: "button",
              onclick: async () => {
                try {
                  await api.logout();
                } finally {
                  ctx.setUser(null);
                  ctx.navigate("#/login");
                }
              },
            }, "Log out"),
          )
        : "",
    );
  }

  async function route() {
    if (typeof cleanup === "function") cleanup();
    cleanup = undefined;
    clear(main);
    const path = location.hash.replace(/^#/, "").split("?")[0] || "/";
    document.body.dataset.page = path.split("/")[1] || "home";
    if (path === "/help") {
      renderHelp(main);
      return;
    }
    if (path === "/login") {
      if (ctx.user) ctx.setUser(null);
      cleanup = renderLogin(main, ctx);
      return;
    }
    if (!ctx.user) {
      try {
        ctx.setUser(await api.me());
      } catch (err) {
        if (err instanceof ApiError && (err.status === 401 || err.status === 403)) {
          ctx.navigate(`#/login?next=${encodeURIComponent(path)}`);
          return;
        }
        main.append(h("p", { class: "error", role: "alert" }, `Cannot load your account: ${(err as Error).message}`));
        return;
      }
    }
    const m = path.match(/^\/runs\/([^/?]+)/);
    if (path.startsWith("/tasks")) cleanup = renderTasksRoute(path, main, ctx);
    else if (path.startsWith("/floors")) cleanup = renderFloorsRoute(path, main, ctx);
    else if (m) cleanup = renderEditor(main, ctx, decodeURIComponent(m[1]));
    else if (path.startsWith("/admin/runs")) cleanup = renderAdminRuns(main, ctx);
    else if (path.startsWith("/admin/tiles")) cleanup = renderAdminTiles(main, ctx);
    else if (path.startsWith("/admin/people")) cleanup = renderAdminPeople(path, main, ctx);
    else cleanup = renderHome(main, ctx);
  }

  renderHeader();
  installHelpOverlay(root);
  window.addEventListener("hashchange", route);
  route();
}
