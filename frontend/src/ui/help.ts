/**
 * Help: the `?` overlay listing every shortcut (from the editor's and the review queue's key
 * tables, so it cannot drift from the keys), and the help page (#/help) linked from the top
 * bar, which can also restart the first-run tour.
 */
import { EDITOR_SHORTCUTS } from "../behaviors/keyboard";
import { STATUS_COLORS, STATUS_LABELS } from "../map/features";
import { REVIEW_SHORTCUTS } from "../tasks/format";
import { h } from "./dom";
import { restartTour } from "./editor/tour";

const KEY_NAMES: Record<string, string> = { ArrowRight: "→", ArrowLeft: "←", ArrowUp: "↑", ArrowDown: "↓", Delete: "Del", Escape: "Esc" };

/** `["Ctrl+Z", "Ctrl+Y"]` as key caps: Ctrl+Z / Ctrl+Y. */
export function keyCaps(keys: readonly string[]): (Node | string)[] {
  const out: (Node | string)[] = [];
  keys.forEach((k, i) => {
    if (i > 0) out.push(" / ");
    const name = k.length > 1 ? k.split("+").map((part) => KEY_NAMES[part] ?? part).join("+") : k;
    out.push(h("kbd", { title: k }, name));
  });
  return out;
}

function shortcutTable(caption: string, rows: { keys: string[]; what: string; when?: string }[], testId: string): HTMLElement {
  return h("table", { class: "table shortcuts", "data-testid": testId },
    h("caption", {}, caption),
    h("thead", {}, h("tr", {}, h("th", { scope: "col" }, "Keys"), h("th", { scope: "col" }, "Does"))),
    h("tbody", {}, ...rows.map((r) => h("tr", { "data-keys": r.keys.join(" ") },
      h("td", {}, ...keyCaps(r.keys)),
      h("td", {}, r.what, r.when === "suggestions" ? h("span", { class: "muted" }, " (while suggestions are on the map)") : "")))));
}

/** Every shortcut of the app, by page. */
export function shortcutTables(): HTMLElement[] {
  return [
    shortcutTable("Correcting a run (the editor)", EDITOR_SHORTCUTS, "shortcuts-editor"),
    shortcutTable("Review queue", REVIEW_SHORTCUTS, "shortcuts-review"),
    shortcutTable("Anywhere", [{ keys: ["?"], what: "This list of shortcuts" }, { keys: ["Escape"], what: "Close it" }], "shortcuts-anywhere"),
  ];
}

/** The `?` overlay: one modal dialog for the whole app, opened by `?` anywhere but in a text field. */
export function installHelpOverlay(root: HTMLElement): () => void {
  const dialog = h("dialog", { class: "help-dialog", "aria-labelledby": "help-title", "data-testid": "help-overlay" });
  const close = h("button", { type: "button", "aria-label": "Close the shortcuts", onclick: () => dialog.close() }, "×");
  dialog.append(
    h("div", { class: "row spread" }, h("h2", { id: "help-title" }, "Keyboard shortcuts"), close),
    ...shortcutTables(),
    h("p", {}, h("a", { href: "#/help", onclick: () => dialog.close() }, "Help page"), " · ",
      h("button", { type: "button", class: "link", "data-testid": "overlay-tour", onclick: () => { restartTour(); dialog.close(); } }, "Take the tour again"),
      h("span", { class: "muted" }, " (in the run you are editing, or the next one you open)")),
  );
  root.append(dialog);
  const onKey = (e: KeyboardEvent) => {
    if (e.key !== "?" || e.ctrlKey || e.metaKey || e.altKey) return;
    const t = e.target as HTMLElement | null;
    if (t && (t.tagName === "INPUT" || t.tagName === "TEXTAREA" || t.tagName === "SELECT" || t.isContentEditable)) return;
    e.preventDefault();
    if (dialog.open) dialog.close();
    else dialog.showModal();
  };
  window.addEventListener("keydown", onKey);
  return () => window.removeEventListener("keydown", onKey);
}

/** The help page: how the editor works, what its marks mean, the shortcuts, and the tour. */
export function renderHelp(main: HTMLElement): void {
  const tourMsg = h("p", { role: "status", "data-testid": "tour-msg" });
  const tourBtn = h("button", { type: "button", "data-testid": "restart-tour" }, "Start the tour again");
  tourBtn.addEventListener("click", () => {
    restartTour();
    tourMsg.textContent = "The tour starts the next time you open a run.";
  });
  main.append(h("section", { class: "page help-page", "data-testid": "help-page" },
    h("h1", {}, "Help"),
    h("section", { class: "card" },
      h("h2", {}, "Correcting a run"),
      h("p", {}, "Open a run from ", h("a", { href: "#/" }, "My runs"), " or take a task from ", h("a", { href: "#/tasks/work" }, "Work"),
        ". Drag a keyframe onto where the vehicle really was; the rest of the track follows (the server re-optimises it while you drag). ",
        "Each drag is one step you can undo. Nothing is saved until you press Submit, with an optional comment."),
      h("p", {}, "Some moves break the run's editing rules: only every Nth keyframe may move, a move locks its neighbours, a keyframe may move only so far, ",
        "and the track may not run backwards. A refused move is not made: the reason is shown where you dropped it."),
      h("p", {}, "If someone else saved first, the editor says so and offers to re-apply your edits on top of their revision."),
      h("p", {}, tourBtn), tourMsg),
    h("section", { class: "card" },
      h("h2", {}, "What the colours mean"),
      h("ul", { class: "plain" }, ...(Object.keys(STATUS_LABELS) as (keyof typeof STATUS_LABELS)[]).map((k) =>
        h("li", {}, h("span", { class: "swatch", style: { background: STATUS_COLORS[k] } }), ` ${STATUS_LABELS[k]}`))),
      h("p", {}, "Suggestions from the street map are pink: click one to pick it, then Accept (Enter) or Skip (S). A click never accepts.")),
    h("section", { class: "card" },
      h("h2", {}, "More in the editor"),
      h("p", {}, "History (H) lists every revision with who, when and why; pick two to compare them on the map, or revert to an earlier one (a new revision; nothing is lost). ",
        "Export downloads the shown revision as CSV, GPX or GeoJSON. Images (I) shows the selected keyframe's camera images; ",
        "open the larger view to step through the run's images with the keyframe following on the map.")),
    h("section", { class: "card" }, h("h2", {}, "Keyboard shortcuts"), h("p", { class: "muted" }, "Press ? anywhere to see these."), ...shortcutTables()),
  ));
}
