/**
 * Export in the editor: the shown revision as CSV, GPX or GeoJSON, for anyone who may read
 * the run (the server checks that again on the download). Unsaved edits are not in a saved
 * revision, so the menu says so while there are some.
 */
import { h } from "../dom";

export const EXPORT_FORMATS = [
  { format: "csv", label: "CSV", what: "every sample, full rate" },
  { format: "gpx", label: "GPX", what: "a GPS track" },
  { format: "geojson", label: "GeoJSON", what: "a line and points" },
] as const;

export interface ExportLink {
  label: string;
  href: string;
  filename: string;
  what: string;
}

/** The download links of revision `revision` of run `runId` (a pure function, unit tested). */
export function exportLinks(runId: string, runName: string, revision: number): ExportLink[] {
  const safe = runName.replace(/[^\w.-]+/g, "_").replace(/^_+|_+$/g, "") || `run-${runId}`;
  return EXPORT_FORMATS.map((f) => ({
    label: f.label,
    what: f.what,
    href: `/api/v1/runs/${encodeURIComponent(runId)}/export?format=${f.format}&revision=${revision}`,
    filename: `${safe}-r${revision}.${f.format}`,
  }));
}

/** A disclosure menu in the toolbar with one link per format. */
export class ExportMenu {
  readonly el: HTMLDetailsElement;
  private readonly list = h("ul", { class: "export-list" });
  private readonly note = h("p", { class: "muted export-note", "data-testid": "export-note" });
  private shown: string | null = null;

  constructor(private readonly runId: string) {
    this.el = h("details", { class: "export-menu", "data-testid": "export" },
      h("summary", { title: "Download the shown revision (CSV, GPX, GeoJSON)" }, "Export"),
      h("div", { class: "export-pop" }, this.list, this.note));
    // The menu closes once a format is chosen, or on a click elsewhere.
    this.list.addEventListener("click", (e) => {
      if ((e.target as Element).closest("a")) this.el.open = false;
    });
    document.addEventListener("click", this.onOutside);
  }

  private onOutside = (e: MouseEvent) => {
    if (this.el.open && !this.el.contains(e.target as Node)) this.el.open = false;
  };

  dispose(): void {
    document.removeEventListener("click", this.onOutside);
  }

  /** Point the links at `revision`; `unsaved` edits are mentioned, not exported. */
  render(runName: string, revision: number | null, unsaved: number): void {
    const key = `${runName}|${revision}|${unsaved > 0}`;
    if (key === this.shown) return;
    this.shown = key;
    if (revision === null) {
      this.list.replaceChildren();
      this.note.textContent = "Loading…";
      return;
    }
    this.list.replaceChildren(...exportLinks(this.runId, runName, revision).map((l) =>
      h("li", {}, h("a", { href: l.href, download: l.filename, "data-testid": `export-${l.label.toLowerCase()}` }, `${l.label}`),
        h("span", { class: "muted" }, ` ${l.what}`))));
    this.note.textContent = unsaved > 0
      ? `Revision ${revision} as saved; your unsaved edits are not in it until you submit.`
      : `Revision ${revision}, as shown.`;
  }
}
