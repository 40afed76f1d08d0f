/** Admin: upload a run (with progress) and list runs with their status. */
import { api, uploadRun } from "../api/endpoints";
import { describeError } from "../api/errors";
import type { AppContext } from "./context";
import { fmtTime, h, plural } from "./dom";

export function renderAdminRuns(main: HTMLElement, _ctx: AppContext): () => void {
  const name = h("input", { id: "up-name", name: "name", required: true });
  // The pickers offer what the server accepts: its one list, asked for below.
  const file = h("input", { id: "up-file", name: "file", type: "file", required: true, "aria-describedby": "up-file-kinds" });
  const images = h("input", { id: "up-images", name: "images", type: "file", multiple: true, "aria-describedby": "up-images-kinds" });
  const fileKinds = h("small", { id: "up-file-kinds", class: "hint muted", "data-testid": "run-extensions" });
  const imageKinds = h("small", { id: "up-images-kinds", class: "hint muted" });
  const bar = h("progress", { max: 1, value: 0, "aria-label": "Upload progress" });
  const msg = h("p", { role: "status", "aria-live": "polite" });
  const button = h("button", { type: "submit", class: "primary" }, "Upload");
  const list = h("div");
  const form = h("form", { class: "card", "aria-label": "Upload a run" },
    h("h2", {}, "Upload a run"),
    h("label", { for: "up-name" }, "Name"), name,
    h("label", { for: "up-file" }, "Run file (CSV, Parquet, Arrow, GPX, GeoJSON, TUM; a zipped KITTI or comma2k19 folder)"), file, fileKinds,
    h("label", { for: "up-images" }, "Images (a zip, or several images; optional)"), images, imageKinds,
    button, bar, msg,
  );
  api.uploadFormats().then(
    (f) => {
      file.accept = f.run.join(",");
      images.accept = [".zip", ...f.images].join(",");
      fileKinds.textContent = `Accepted: ${f.run.join(" ")}`;
      imageKinds.textContent = `Accepted: .zip ${f.images.join(" ")}`;
    },
    (err) => (fileKinds.textContent = `The accepted file types could not be loaded: ${describeError(err)}`),
  );
  file.addEventListener("change", () => {
    if (!name.value && file.files?.[0]) name.value = file.files[0].name.replace(/\.[^.]+$/, "");
  });
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    if (!file.files?.[0]) return;
    const fd = new FormData();
    fd.append("name", name.value);
    fd.append("file", file.files[0]);
    for (const f of Array.from(images.files ?? [])) fd.append("images", f);
    button.disabled = true;
    msg.textContent = "Uploading…";
    try {
      const run = await uploadRun(fd, (p) => {
        bar.value = p;
        msg.textContent = `Uploading… ${Math.round(p * 100)}%`;
      });
      msg.textContent = `Uploaded “${run.name}” (status ${run.status}).`;
      form.reset();
      bar.value = 0;
      load();
    } catch (err) {
      msg.textContent = `Upload failed: ${describeError(err)}`;
    } finally {
      button.disabled = false;
    }
  });

  function load() {
    api.listRuns({ limit: 500 }).then(
      (r) =>
        list.replaceChildren(
          h("table", { class: "table", "data-testid": "admin-runs-table" },
            h("thead", {}, h("tr", {}, ...["Run", "Status", "Revision", "Keyframes", "Images", "Created", ""].map((t) => h("th", {}, t)))),
            h("tbody", {}, ...r.items.map((run) =>
              h("tr", {},
                h("td", {}, h("a", { href: `#/runs/${encodeURIComponent(String(run.id))}` }, run.name)),
                h("td", {}, h("span", { class: `status status-${run.status}` }, String(run.status))),
                h("td", {}, run.head_revision > run.revision ? `${run.revision} (computing ${run.head_revision})` : String(run.revision)),
                h("td", {}, String(run.n_keyframes)),
                h("td", {}, String(run.n_images)),
                h("td", {}, fmtTime(run.created_at)),
                h("td", {}, h("a", { href: `/api/v1/runs/${encodeURIComponent(String(run.id))}/export?format=csv` }, "Export CSV")),
              ),
            )),
          ),
          h("p", { class: "muted" }, plural(r.total, "run")),
        ),
      (err) => list.replaceChildren(h("p", { class: "error", role: "alert" }, describeError(err))),
    );
  }
  main.append(h("section", { class: "page" }, h("h1", {}, "Runs"), form, h("section", { class: "card" }, h("h2", {}, "All runs"), list)));
  load();
  const timer = window.setInterval(load, 5000);
  return () => window.clearInterval(timer);
}
