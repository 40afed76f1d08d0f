"""The browser tracker's time per step in headless Chromium, beside the server's, in one run:
``python -m benchmarks.browser_tracker`` (also printed at the end of ``python -m benchmarks.mapmatch``).

Both sides track the same walks with the same model bytes (built from the floor at 0.8 m
cells, f2 on) from the same starts: the server with ``posefix.mapmatch.Tracker`` (the loop
of ``track_walk``), the browser with ``frontend/src/tracker``'s
``trackWalk`` bundled by rolldown and run in Debian's Chromium. Both are wall time of the
step loop (one thread each; ``performance.now()`` is coarsened to 0.1 ms, far below a
walk's total); the server's CPU time is printed beside its wall time, as a measure of the
machine's load. The page tracks the walks three times: the first pass (cold: the JIT still
compiling) is printed beside the third (warm), the figure a phone reaches after a few
dozen steps. Rows: site1/F1, the floor the target is set on (≤ 2 ms per step at 0.8 m cells),
and site2/F2, a floor nothing in the tracker was chosen on (held out); known start (the
first waypoint) and unknown start (every vertex live: the dense worst case).
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

REPO = Path(__file__).resolve().parents[1]
FRONTEND = REPO / "frontend"
CHROMIUM = "/usr/bin/chromium"
TARGET_MS_PER_STEP = 2.0

PAGE_RUN = """async ({model, walks, starts}) => {
  const T = window.PosefixTracker;
  const bytes = Uint8Array.from(atob(model), (c) => c.charCodeAt(0));
  const m = await T.loadModel(bytes);
  const out = [];
  for (let pass = 0; pass < 3; pass++) {
    let steps = 0, ms = 0;
    walks.forEach((text, i) => {
      const run = T.trackWalk(m, T.parseWalk(text), starts[i]);
      const n = run.t_ms.length - 1;
      steps += n;
      ms += run.ms_per_step * n;
    });
    out.push({steps, ms});
  }
  return out;
}"""


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
    of ``track_walk`` (detected steps fed to ``Tracker.step``), timed as the page times its own."""
    from posefix.mapmatch import Tracker
    from posefix.mapmatch.sensors import steps_from_walk

    steps, wall, cpu = 0, 0.0, 0.0
    for w, s in zip(walks, starts):
        st = steps_from_walk(w)
        vec = st.vectors_m(model.step_model)
        tr = Tracker(model, start_xy_m=None if s is None else tuple(s), t0_ms=int(w.acc[0, 0]))
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(len(st)):
            tr.step(vec[i], int(st.t_ms[i]))
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
                for start in ("known", "unknown"):
                    starts = [[float(w.waypoints[0, 1]), float(w.waypoints[0, 2])] if start == "known" else None for w in walks]
                    passes = page.evaluate(PAGE_RUN, {"model": base64.b64encode(data).decode(), "walks": texts, "starts": starts})
                    cold, warm = passes[0], passes[-1]
                    n, wall, cpu = server_ms(model, walks, starts)
                    if n != warm["steps"]:
                        raise RuntimeError(f"{name}: the browser detected {warm['steps']} steps, the server {n}")
                    rows.append({"floor": name, "start": start, "walks": len(walks), "steps": n,
                                 "cold": cold["ms"] / n, "warm": warm["ms"] / n, "server": wall / n, "server_cpu": cpu / n})
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
    print("\nbrowser tracker (frontend/src/tracker in headless Chromium) vs server (Python), same model bytes and walks, 0.8 m cells")
    hdr = (f"{'floor, start':34s} {'walks':>5s} {'steps':>6s}  {'browser warm ms/step (÷2.0)':>28s}  {'cold':>6s}  "
           f"{'server ms/step':>14s}  {'(CPU)':>6s}  {'browser ÷ server':>16s}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(f"{r['floor'] + ', ' + r['start'] + ' start':34s} {r['walks']:5d} {r['steps']:6d}  "
              f"{r['warm']:17.2f} ({r['warm'] / TARGET_MS_PER_STEP:4.2f}×)  {r['cold']:6.2f}  {r['server']:14.2f}  "
              f"{r['server_cpu']:6.2f}  {r['warm'] / r['server']:15.2f}×")
    print("(wall time of the step loop on both sides; browser warm = third pass over the walks, cold = first;"
          " server CPU beside its wall time shows how loaded the machine was)")


def main() -> int:
    print_browser_block()
    return 0


if __name__ == "__main__":
    sys.exit(main())
