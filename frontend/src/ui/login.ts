import { api } from "../api/endpoints";
import { describeError } from "../api/errors";
import type { AppContext } from "./context";
import { h } from "./dom";

export function renderLogin(main: HTMLElement, ctx: AppContext): void {
  const next = new URLSearchParams(location.hash.split("?")[1] ?? "").get("next") || "/";
  const msg = h("p", { class: "error", role: "alert", "aria-live": "assertive" });
  const user = h("input", { id: "login-username", name: "username", autocomplete: "username", required: true });
  const pass = h("input", { id: "login-password", name: "password", type: "password", autocomplete: "current-password", required: true });
  const button = h("button", { type: "submit", class: "primary" }, "Log in");
  const form = h(
    "form",
    { class: "card login", "aria-label": "Log in" },
    h("h1", {}, "Log in to posefix"),
    h("label", { for: "login-username" }, "Username"),
    user,
    h("label", { for: "login-password" }, "Password"),
    pass,
    button,
    msg,
  );
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    msg.textContent = "";
    button.disabled = true;
    try {
      const u = await api.login(user.value, pass.value);
      ctx.setUser(u);
      ctx.navigate(`#${next}`);
    } catch (err) {
      msg.textContent = describeError(err);
    } finally {
      button.disabled = false;
    }
  });
  main.append(form);
  user.focus();
}
