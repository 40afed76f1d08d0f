/**
 * Parity of the browser tracker with the Python online filter, live: the test runs the
 * project's Python (tests/vectors/tracker_parity.py) on the repository's walks of both
 * floors, then tracks the same walks with the TypeScript tracker from the same model and
 * fingerprint bytes, and compares every step's live position.
 */
import { execFileSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { afterAll, describe, expect, it } from "vitest";
import { type Modes, Tracker, loadFingerprints, loadModel, parseWalk, posteriorModes, trackWalk } from "../src/tracker";

const REPO = resolve(__dirname, "../..");
const PYTHON = process.env.POSEFIX_PYTHON ?? join(REPO, ".venv/bin/python");
const TOL_M = 0.05;

interface PyModes {
  mass: number[];
  mean: [number, number][];
  spread_m: number;
  sigma_major_m: number;
  converged: boolean;
}

/** The same modes and the same converged flag (a flag may differ only on its threshold's edge). */
function expectSameModes(ts: Modes, py: PyModes, where: string): void {
  const edge = Math.abs(py.mass[0] - 0.95) < 1e-9 || Math.abs(py.sigma_major_m - 5) < 1e-9;
  if (!edge) expect(ts.converged, `${where}: converged`).toBe(py.converged);
  expect(ts.modes.length, `${where}: modes`).toBe(py.mass.length);
  ts.modes.forEach((m, j) => {
    expect(Math.abs(m.mass - py.mass[j]), `${where}: mode ${j} mass`).toBeLessThanOrEqual(1e-9);
    expect(Math.hypot(m.x - py.mean[j][0], m.y - py.mean[j][1]), `${where}: mode ${j} mean`).toBeLessThanOrEqual(TOL_M);
  });
  expect(Math.abs(ts.spread_m - py.spread_m), `${where}: spread`).toBeLessThanOrEqual(TOL_M);
  expect(Math.abs(ts.sigma_major_m - py.sigma_major_m), `${where}: sigma`).toBeLessThanOrEqual(TOL_M);
}

interface Case {
  name: string;
  walk: string;
  model: string;
  fingerprints: string | null;
  start: [number, number] | null;
  t_ms: number[];
  x: number[];
  y: number[];
  sigma_major_m: number[];
  modes: PyModes[];
  ms_per_step: number;
}

const out = mkdtempSync(join(tmpdir(), "tracker-parity-"));
afterAll(() => rmSync(out, { recursive: true, force: true }));

function pythonCases(): Case[] {
  execFileSync(PYTHON, ["-m", "tests.vectors.tracker_parity", out], { cwd: REPO, stdio: ["ignore", "ignore", "inherit"], timeout: 300_000 });
  return JSON.parse(readFileSync(join(out, "cases.json"), "utf8"));
}

describe("browser tracker vs the Python online filter (same model bytes, same walks)", () => {
  const cases = pythonCases();

  it("covers both floors, known and unknown starts, with and without WiFi", () => {
    const names = cases.map((c) => c.name).join("\n");
    expect(names).toMatch(/site1 .* known start\n/);
    expect(names).toMatch(/site2 .* known start\n/);
    expect(names).toMatch(/unknown start \+ WiFi/);
    expect(cases.length).toBeGreaterThanOrEqual(8);
  });

  for (const c of cases) {
    it(`${c.name}: every step within ${TOL_M} m`, async () => {
      const model = await loadModel(new Uint8Array(readFileSync(c.model)), c.model);
      const fp = c.fingerprints ? await loadFingerprints(new Uint8Array(readFileSync(c.fingerprints)), c.fingerprints) : null;
      const walk = parseWalk(readFileSync(c.walk, "utf8"), c.walk);
      const run = trackWalk(model, walk, c.start, fp);
      expect(Array.from(run.t_ms)).toEqual(c.t_ms);
      let worst = 0;
      let at = -1;
      for (let i = 0; i < c.x.length; i++) {
        const d = Math.hypot(run.x[i] - c.x[i], run.y[i] - c.y[i]);
        if (d > worst) (worst = d), (at = i);
      }
      expect(worst, `largest difference ${worst} m at step ${at}`).toBeLessThanOrEqual(TOL_M);
      for (let i = 0; i < c.x.length; i++) expect(Math.abs(run.sigma_major_m[i] - c.sigma_major_m[i])).toBeLessThanOrEqual(TOL_M);
      for (let i = 0; i < c.x.length; i++) expectSameModes(run.modes[i], c.modes[i], `step ${i}`);
    });
  }
});

describe("model and fingerprint files: errors name the file and the member", () => {
  it("refuses bytes that are not a zip, and a fingerprint file given as a model", async () => {
    await expect(loadModel(new Uint8Array([1, 2, 3, 4]), "junk.npz")).rejects.toThrow("junk.npz:0: field file: not a zip");
    const fpFile = join(out, "site1-fp.npz");
    await expect(loadModel(new Uint8Array(readFileSync(fpFile)), "fp.npz")).rejects.toThrow(/fp\.npz:0: field format: expected 'posefix-mapmatch'/);
    await expect(loadFingerprints(new Uint8Array(readFileSync(join(out, "site1.npz"))), "m.npz")).rejects.toThrow("m.npz:0: field format: not a posefix fingerprint file");
  });

  it("reads the model's grid and parameters as written", async () => {
    const m = await loadModel(new Uint8Array(readFileSync(join(out, "site1.npz"))));
    expect(m.graph.n).toBeGreaterThan(10_000);
    expect(m.graph.k).toBe(13);
    expect(m.weights).toEqual({ f1: 0.8, f2: 0.4, f3: 1.0, f4: 0.5 });
    expect(m.step.heading_bias_rad).toBeCloseTo(0.07, 12);
    expect(m.sigmas.wifi_corr_s).toBe(20);
    expect(m.georef).not.toBeNull();
  });
});

describe("modes and the converged flag: posefix.mapmatch.modes on the same distributions", () => {
  const modeCases: (PyModes & { name: string; model: string; prob: number[] })[] = JSON.parse(readFileSync(join(out, "modes.json"), "utf8"));

  it("covers ties, near and far second places, a long blob and several places", () => {
    expect(modeCases.map((c) => c.converged)).toContain(true);
    expect(modeCases.some((c) => !c.converged && c.mass[0] >= 0.95)).toBe(true); // one place, not a fix
    expect(modeCases.some((c) => c.converged && c.mass.length > 1)).toBe(true); // a second place counted, still a fix
    expect(modeCases.some((c) => c.mass.length > 1 && c.mass[0] === c.mass[1])).toBe(true);
  });

  for (const c of modeCases) {
    it(c.name, async () => {
      const m = await loadModel(new Uint8Array(readFileSync(c.model)), c.model);
      const w = Float64Array.from(c.prob);
      const live = Int32Array.from(c.prob.flatMap((p, v) => (p > 0 ? [v] : [])));
      expectSameModes(posteriorModes(m.graph.px, m.graph.py, w, live), c, c.name);
    });
  }

  it("a known start is one converged mode; an unknown start is one place over the floor, not converged", async () => {
    const m = await loadModel(new Uint8Array(readFileSync(join(out, "site1.npz"))));
    const known = new Tracker(m, { start: [81.3, 93.3] }).modes();
    expect(known.modes).toHaveLength(1);
    expect(known.converged).toBe(true);
    const unknown = new Tracker(m, {}).modes();
    expect(unknown.converged).toBe(false);
    expect(unknown.sigma_major_m).toBeGreaterThan(20);
  });
});
