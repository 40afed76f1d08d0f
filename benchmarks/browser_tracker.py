"""The browser tracker's time per step in headless Chromium, beside the server's, in one run:
``python -m benchmarks.browser_tracker`` (also printed at the end of ``python -m benchmarks.mapmatch``).

Both sides track the same walks with the same model bytes (built from the floor at 0.8 m
cells, f2 on) from the same starts: the server with ``posefix.mapmatch.Tracker`` (the loop
of ``track_walk``), the browser with ``frontend/src/tracker``'s ``trackWalk`` bundled by
rolldown and run in Debian's Chromium. A step is what a live step costs: both filters, the
Gaussian summary, and the posterior's modes and converged flag (``posefix.mapmatch.modes``).

Timing: the machine this runs on is shared and often loaded, so wall time mostly measures
the queue for a core. Both sides are therefore measured in CPU time too: the server's step
loop with ``time.process_time``, the browser by the Chromium renderer processes' CPU time
(``/proc``) around the warm passes; the target (≤ 2 ms per step at 0.8 m cells on
site1/F1) and the ratio are read on CPU time, wall time printed beside. The page tracks the
walks once cold (the JIT still compiling; wall time) and then four times warm, the figure a
phone reaches after a few dozen steps. Rows: site1/F1, the floor the target is set on, and
site2/F2, a floor nothing in the tracker was chosen on (held out); known start (the first
waypoint) and unknown start (every vertex live: the dense worst case).
"""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from benchmarks.proc import descendants_cpu_s

REPO = Path(__file__).resolve().parents[1]
FRONTEND = REPO / "frontend"
CHROMIUM = "/usr/bin/chromium"
TARGET_MS_PER_STEP = 2.0

WARM_PASSES = 4

# The model is read and the walks' steps detected once per floor (window.__m, __steps); each
# run then times what the server's loop does: a Tracker fed the steps, with each step's modes.
PAGE_LOAD = """async ({model, walks}) => {
  const T = window.PosefixTracker;
  const bytes = Uint8Array.from(atob(model), (c) => c.charCodeAt(0));
  window.__m = await T.loadModel(bytes);
  window.__steps = walks.map((text) => T.stepsFromWalk(T.parseWalk(text)));
  window.__t0 = walks.map((text) => Math.trunc(T.parseWalk(text).acc.t[0]));
}"""

PAGE_RUN = """({starts, passes}) => {
  const T = window.PosefixTracker;
  const m = window.__m;
  let steps = 0, ms = 0;
  for (let pass = 0; pass < passes; pass++) {
    window.__steps.forEach((st, i) => {
      const tr = new T.Tracker(m, {start: starts[i], t0_ms: window.__t0[i]});
      const tic = performance.now();
      for (let j = 0; j < st.t_ms.length; j++) {
        const [sx, sy] = T.stepVector(m.step, st.freq_hz[j], st.heading_rad[j]);
        tr.step(sx, sy, st.t_ms[j]);
        tr.modes();
      }
      ms += performance.now() - tic;
      steps += st.t_ms.length;
    });
  }
  return {steps, ms};
}"""


def renderer_cpu_s() -> float | None:
    """CPU seconds (user + system) used so far by the Chromium renderer processes this process
    started (Linux /proc; None elsewhere): the browser side's CPU time, as the server's is
    measured, so that both can be compared on a loaded machine."""
    return descendants_cpu_s(b"--type=renderer")


def bundle() -> str:
    """The tracker as one script defining ``window.PosefixTracker``."""
    exe = FRONTEND / "node_modules" / ".bin" / "rolldown"
    if not exe.exists():
        raise RuntimeError(f"{exe} not found: run ./scripts/setup.sh (it installs the front end's packages)")
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "tracker.js"
        subprocess.run([str(exe), str(FRONTEND / "src" / "tracker" / "index.ts"), "--format", "iife",
                        "--name", "PosefixTracker", "--file", str(out)], check=True, cwd=FRONTEND, capture_output=True)
        return out.read_text()


def bench_model(floor: Path):
    from posefix.mapmatch import build_model

    model = build_model(floor, cell_m=0.8)
    return model.with_(weights={**model.weights, "f2": 0.5})


def server_ms(model, walks, starts) -> tuple[int, float, float]:
    """Steps, and the online step's wall and CPU time (ms) summed over the walks: the loop
    of ``track_walk`` (detected steps fed to ``Tracker.step``, then the column's modes and
    converged flag), timed as the page times its own."""
    import numpy as np

    from posefix.mapmatch import Tracker
    from posefix.mapmatch.modes import posterior_modes
    from posefix.mapmatch.sensors import steps_from_walk

    steps, wall, cpu = 0, 0.0, 0.0
    for w, s in zip(walks, starts):
        st = steps_from_walk(w)
        vec = st.vectors_m(model.step_model)
        tr = Tracker(model, start_xy_m=None if s is None else tuple(s), t0_ms=int(w.acc[0, 0]))
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(len(st)):
            tr.step(vec[i], int(st.t_ms[i]))
            posterior_modes(tr.p_xy_m, np.exp(tr.column()))
        wall += 1000.0 * (time.perf_counter() - t0)
        cpu += 1000.0 * (time.process_time() - c0)
        steps += len(st)
    return steps, wall, cpu


def browser_rows(floors: dict[str, Path]) -> list[dict]:
    """Per floor and start: steps, browser cold/warm ms per step, server ms per step."""
    from playwright.sync_api import sync_playwright

    from posefix.mapmatch import load_model, read_walk
    from posefix.mapmatch.model import model_bytes

    script = bundle()
    rows = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.goto("about:blank")
            page.add_script_tag(content=script)
            for name, floor in floors.items():
                data = model_bytes(bench_model(floor))
                with tempfile.NamedTemporaryFile(suffix=".npz") as f:
                    f.write(data)
                    f.flush()
                    model = load_model(f.name)  # the server reads the very bytes the page gets
                paths = sorted((floor / "walks").glob("*.txt"))
                walks = [read_walk(w) for w in paths]
                texts = [w.read_text(encoding="utf-8", errors="replace") for w in paths]
                page.evaluate(PAGE_LOAD, {"model": base64.b64encode(data).decode(), "walks": texts})
                for start in ("known", "unknown"):
                    starts = [[float(w.waypoints[0, 1]), float(w.waypoints[0, 2])] if start == "known" else None for w in walks]
                    arg = {"starts": starts}
                    cold = page.evaluate(PAGE_RUN, {**arg, "passes": 1})
                    c0 = renderer_cpu_s()
                    warm = page.evaluate(PAGE_RUN, {**arg, "passes": WARM_PASSES})
                    c1 = renderer_cpu_s()
                    n, wall, cpu = server_ms(model, walks, starts)
                    if n * WARM_PASSES != warm["steps"]:
                        raise RuntimeError(f"{name}: the browser detected {warm['steps'] // WARM_PASSES} steps, the server {n}")
                    rows.append({"floor": name, "start": start, "walks": len(walks), "steps": n,
                                 "cold": cold["ms"] / n, "warm": warm["ms"] / warm["steps"],
                                 "warm_cpu": None if c0 is None else 1000.0 * (c1 - c0) / warm["steps"],
                                 "server": wall / n, "server_cpu": cpu / n})
        finally:
            browser.close()
    return rows


def print_browser_block(site1: Path | None = None) -> None:
    """The browser-vs-server block (``site1``: the site1/F1 folder to use; default the repository's)."""
    floors = {"site1/F1": site1 or REPO / "data" / "indoor-site1-F1",
              "site2/F2 (held out)": REPO / "data" / "indoor-site2-F2"}
    try:
        rows = browser_rows(floors)
    except Exception as exc:  # noqa: BLE001 - the block says why it is missing, the rest of the benchmark stands
        print(f"\nbrowser tracker: not measured ({type(exc).__name__}: {exc})")
        return
    print("\nbrowser tracker (frontend/src/tracker in headless Chromium) vs server (Python), same model bytes and walks, 0.8 m cells;"
          " a step = both filters, the summary, the modes and converged")
    hdr = (f"{'floor, start':34s} {'walks':>5s} {'steps':>6s}  {'browser CPU ms/step (÷2.0)':>27s}  {'wall':>5s}  {'cold':>5s}  "
           f"{'server CPU':>10s}  {'wall':>5s}  {'browser ÷ server (CPU)':>22s}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        cpu = r["warm_cpu"] if r["warm_cpu"] is not None else r["warm"]
        print(f"{r['floor'] + ', ' + r['start'] + ' start':34s} {r['walks']:5d} {r['steps']:6d}  "
              f"{cpu:16.2f} ({cpu / TARGET_MS_PER_STEP:4.2f}×)  {r['warm']:5.2f}  {r['cold']:5.2f}  "
              f"{r['server_cpu']:10.2f}  {r['server']:5.2f}  {cpu / r['server_cpu']:21.2f}×")
    print(f"(browser: the renderer's CPU time over {WARM_PASSES} warm passes (after one cold pass: 'cold', wall) and their"
          " wall time; server: the step loop's CPU and wall time. Wall time far above CPU time means a loaded machine;"
          " the target is read on CPU time, one core.)")


def main() -> int:
    print_browser_block()
    return 0


if __name__ == "__main__":
    sys.exit(main())
