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
import { Tracker, loadFingerprints, loadModel, parseWalk, trackWalk } from "../src/tracker";

const REPO = resolve(__dirname, "../..");
const PYTHON = process.env.POSEFIX_PYTHON ?? join(REPO, ".venv/bin/python");
const TOL_M = 0.05;

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

describe("modes and the converged flag", () => {
  it("a known start is one mode; an unknown start is many, and not converged", async () => {
    const m = await loadModel(new Uint8Array(readFileSync(join(out, "site1.npz"))));
    const known = new Tracker(m, { start: [81.3, 93.3] });
    expect(known.modes()).toHaveLength(1);
    expect(known.converged()).toBe(true);
    const unknown = new Tracker(m, {});
    const modes = unknown.modes();
    expect(modes.length).toBeGreaterThan(50);
    expect(unknown.converged()).toBe(false);
    const total = modes.reduce((a, b) => a + b.mass, 0);
    expect(total).toBeGreaterThanOrEqual(0.99);
    expect(total).toBeLessThanOrEqual(1 + 1e-9);
    for (let i = 1; i < modes.length; i++) expect(modes[i].mass).toBeLessThanOrEqual(modes[i - 1].mass);
  });
});
