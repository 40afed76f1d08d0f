"""Browser editor benchmark: frame time while dragging a keyframe, and wheel-zooming, with 10,000 keyframes.

    python -m benchmarks.editor_drag [--keyframes 10000] [--moves 120] [--zoom-steps 6]

A real `posefix serve` (temporary SQLite database, Helsinki basemap) serves a simulated
drive with one keyframe per second; Debian's Chromium (headless, software WebGL through
--disable-gpu, as in the tests) opens it in the editor with the whole run in view, then
drags one keyframe across the map with --moves pointer moves. A requestAnimationFrame loop
records the time of every frame; the figure is the frame interval during the drag, against
the 16.7 ms budget of a 60 Hz display (ratio < 1: within budget).

For comparison the same loop also runs with the map idle, and while panning the map by
the same pointer path (MapLibre's own interaction, the floor for any layer drawn on it).

Wheel zoom: --zoom-steps mouse-wheel notches over the run (half in, then half out), each
left to settle before the next. Per step, the time from the wheel event to the map's next
`idle` (animation over, every tile drawn), with the frame intervals meanwhile and the
Chromium processes' CPU seconds beside the wall time. The same steps are then taken with
the editor's layers hidden (MapLibre drawing the basemap alone, its own cost), after a warm
pass that loads every tile the steps need, so neither pass waits for the tile server; the
ratio says how much of a slow zoom step is the editor's. Nothing here is tuned, so there is
no held-out part to report.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.e2e.helpers import keyframe_px, login  # noqa: E402
from tests.e2e.serverkit import chromium, ensure_frontend_built, running_server  # noqa: E402
from benchmarks.proc import descendants_cpu_s  # noqa: E402

BUDGET_MS = 1000 / 60
RULES = "[rules]\nevery_n = 1\nlock_n = 0\nmax_move_m = 10000.0\n"

# One recorder at a time: a generation number stops the previous loop for good.
RECORD = """() => { const gen = (window.__gen || 0) + 1; window.__gen = gen; const frames = window.__frames = [];
  const tick = (t) => { if (window.__gen !== gen) return; frames.push(t); requestAnimationFrame(tick); };
  requestAnimationFrame(tick); }"""
STOP = "() => { window.__gen += 1; return window.__frames; }"


# The wheel event's time (page clock) and the first `idle` after it.
ARM_ZOOM = """() => { const m = window.__posefixMap; window.__wheelAt = null; window.__idleAt = null;
  if (!window.__wheelHooked) { window.__wheelHooked = true;
    m.getCanvasContainer().addEventListener('wheel', () => { if (window.__wheelAt === null) window.__wheelAt = performance.now(); }, {capture: true}); }
  m.once('idle', () => { window.__idleAt = performance.now(); }); }"""
WHEEL_PX = 300
EDITOR_LAYERS = "() => window.__posefixMap.getStyle().layers.map(l => l.id).filter(id => id.startsWith('pf-'))"


def chromium_cpu_s() -> float | None:
    """CPU seconds (user + system) so far of the Chromium processes under this one (Linux /proc):
    the renderer and the GPU process, where software WebGL draws."""
    return descendants_cpu_s(b"chrom")


def wheel_zoom(page, at: tuple[float, float], steps: int, view: dict) -> tuple[list[float], list[float], float, float]:
    """Zoom by `steps` wheel notches at `at` from `view`, each settled before the next.
    Returns the frame intervals, the settle time (ms) of each step, CPU and wall seconds."""
    page.evaluate("(v) => window.__posefixMap.jumpTo(v)", view)
    page.wait_for_function("() => window.__posefixMap.loaded() && !window.__posefixMap.isMoving()", timeout=120_000)
    page.mouse.move(*at)
    page.evaluate(RECORD)
    cpu0, t0 = chromium_cpu_s(), time.perf_counter()
    settle = []
    for i in range(steps):
        page.evaluate(ARM_ZOOM)
        page.mouse.wheel(0, -WHEEL_PX if i < (steps + 1) // 2 else WHEEL_PX)
        page.wait_for_function("() => window.__wheelAt !== null && window.__idleAt !== null", timeout=300_000)
        settle.append(page.evaluate("() => window.__idleAt - window.__wheelAt"))
    wall, cpu = time.perf_counter() - t0, chromium_cpu_s() - cpu0
    return intervals(page.evaluate(STOP)), settle, cpu, wall


def zoom_summary(name: str, settle: list[float], cpu_s: float, wall_s: float) -> str:
    return (f"{name:<34} {len(settle):>6} {statistics.median(settle):>10.0f} {max(settle):>10.0f}"
            f" {cpu_s:>9.2f} {wall_s:>9.2f}")


def intervals(frames: list[float]) -> list[float]:
    return [b - a for a, b in zip(frames, frames[1:])]


def summary(name: str, ivals: list[float]) -> str:
    if len(ivals) < 2:
        return f"{name:<34} (too few frames)"
    s = sorted(ivals)
    p95 = s[min(len(s) - 1, int(round(0.95 * (len(s) - 1))))]
    mean = statistics.fmean(ivals)
    return (f"{name:<34} {len(ivals):>6} {mean:>9.1f} {statistics.median(ivals):>9.1f} {p95:>9.1f} {max(ivals):>9.1f}"
            f" {1000 / mean:>7.1f} {p95 / BUDGET_MS:>12.2f}")


def pointer_path(page, start: tuple[float, float], moves: int) -> float:
    """Press at `start`, move in a loop around it, release; returns seconds taken."""
    import math

    t0 = time.perf_counter()
    page.mouse.move(*start)
    page.mouse.down()
    for i in range(1, moves + 1):
        a = 2 * math.pi * i / moves
        page.mouse.move(start[0] + 120 * math.sin(a), start[1] + 60 * (1 - math.cos(a)))
    page.mouse.up()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keyframes", type=int, default=10_000, help="keyframes in the run (one per second)")
    ap.add_argument("--moves", type=int, default=120, help="pointer moves in the drag")
    ap.add_argument("--zoom-steps", type=int, default=6, help="wheel notches (half in, half out)")
    args = ap.parse_args()

    ensure_frontend_built()
    with tempfile.TemporaryDirectory(prefix="posefix-bench-") as tmp, running_server(Path(tmp) / "bench", RULES) as srv:
        print(f"simulating a {args.keyframes} s drive at 1 Hz ...", flush=True)
        sim = srv.simulate("sim", duration_s=args.keyframes, rate_hz=1, seed=5, regime="white")
        t0 = time.perf_counter()
        run_id = srv.upload_run("bench", sim / "run.csv", timeout_s=600)
        n_kf = srv.get_json("op1", f"/api/v1/runs/{run_id}")["n_keyframes"]
        print(f"uploaded run {run_id}: {n_kf} keyframes, ready in {time.perf_counter() - t0:.1f} s", flush=True)
        with chromium() as browser:
            page = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
            login(page, srv)
            t0 = time.perf_counter()
            page.goto(f"{srv.base_url}/#/runs/{run_id}")
            page.wait_for_function(
                """() => { const m = window.__posefixMap; return m && m.getSource('pf-keyframes') && m.loaded()
                      && m.queryRenderedFeatures({layers: ['pf-kf-hit']}).length > 0; }""",
                timeout=120_000,
            )
            page.wait_for_function("() => window.__posefixMap.loaded() && !window.__posefixMap.isMoving()", timeout=60_000)
            print(f"editor open with {n_kf} keyframes drawn in {time.perf_counter() - t0:.1f} s", flush=True)
            drawn = page.evaluate("() => { const f = window.__posefixMap.getSource('pf-keyframes')._data; return (f.geojson || f).features.length; }")

            page.evaluate(RECORD)
            page.wait_for_timeout(2000)
            idle = intervals(page.evaluate(STOP))

            # Pan: press on empty map (top-right corner area), same pointer path.
            page.evaluate(RECORD)
            pan_s = pointer_path(page, (900, 200), args.moves)
            pan = intervals(page.evaluate(STOP))
            page.wait_for_function("() => !window.__posefixMap.isMoving()")

            print("dragging a keyframe ...", flush=True)
            # Drag: press on a keyframe in the middle of the run.
            index = n_kf // 2
            start = keyframe_px(page, index)
            page.evaluate(RECORD)
            drag_s = pointer_path(page, start, args.moves)
            drag = intervals(page.evaluate(STOP))
            page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '1'", timeout=60_000)
            page.wait_for_function("() => document.querySelector('.editor').dataset.previewCurrent === 'true'", timeout=120_000)

            print("wheel-zooming ...", flush=True)
            # Wheel zoom over the middle of the run: a warm pass, then the editor, then the basemap alone.
            view = page.evaluate("() => { const m = window.__posefixMap; const c = m.getCenter(); return {center: [c.lng, c.lat], zoom: m.getZoom(), bearing: 0}; }")
            at = keyframe_px(page, index)
            wheel_zoom(page, at, args.zoom_steps, view)
            zoom_ed = wheel_zoom(page, at, args.zoom_steps, view)
            for layer in page.evaluate(EDITOR_LAYERS):
                page.evaluate("(id) => window.__posefixMap.setLayoutProperty(id, 'visibility', 'none')", layer)
            zoom_base = wheel_zoom(page, at, args.zoom_steps, view)
            zooms = page.evaluate("() => window.__posefixMap.getZoom()")

    print()
    print(f"Editor drag benchmark: {drawn} keyframes on screen, {args.moves} pointer moves "
          f"(drag {drag_s:.1f} s, pan {pan_s:.1f} s), headless Chromium with software WebGL")
    print(f"{'phase':<34} {'frames':>6} {'mean ms':>9} {'p50 ms':>9} {'p95 ms':>9} {'max ms':>9} {'fps':>7} {'p95/16.7ms':>12}")
    print(summary("idle map (rAF floor)", idle))
    print(summary("pan the map (MapLibre baseline)", pan))
    print(summary("drag a keyframe (posefix)", drag))
    print(summary("wheel zoom, editor (posefix)", zoom_ed[0]))
    print(summary("wheel zoom, basemap alone (MapLibre)", zoom_base[0]))
    print()
    print(f"Wheel zoom: {args.zoom_steps} notches of {WHEEL_PX} px from zoom {view['zoom']:.2f} (back at {zooms:.2f}),"
          " each from the wheel event to the map's idle")
    print(f"{'phase':<34} {'steps':>6} {'p50 ms':>10} {'max ms':>10} {'CPU s':>9} {'wall s':>9}")
    print(zoom_summary("editor (posefix)", zoom_ed[1], zoom_ed[2], zoom_ed[3]))
    print(zoom_summary("basemap alone (MapLibre)", zoom_base[1], zoom_base[2], zoom_base[3]))
    print(f"ratio editor / MapLibre: settle p50 {statistics.median(zoom_ed[1]) / statistics.median(zoom_base[1]):.2f},"
          f" CPU {zoom_ed[2] / max(zoom_base[2], 1e-9):.2f}")
    print(f"budget: {BUDGET_MS:.1f} ms per frame (60 Hz); machine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
          " (software WebGL shares those cores: compare drag with pan, not only with the budget)")


if __name__ == "__main__":
    main()
