/**
 * The browser tracker's share of the calibration: WiFi information capped by the survey's
 * walk-long error correlation, and ellipses scaled by the model's ellipse_scale, as in
 * posefix.mapmatch (features.capped_information, viterbi.gaussian_summary's cov_scale).
 */
import { describe, expect, it } from "vitest";
import { gaussianSummary } from "../src/tracker/filters";
import type { Graph } from "../src/tracker/model";
import { cappedInformation } from "../src/tracker/tracker";

function equicorrelatedInformation(n: number, rho: number): number {
  // 1ᵀC⁻¹1 for C = (1 − ρ)I + ρ11ᵀ, by Sherman–Morrison.
  return n / (1 - rho + n * rho);
}

describe("walk-long WiFi correlation", () => {
  it("caps n fixes at the information of equally correlated observations, never above 1/ρ", () => {
    for (const rho of [0.1, 0.3, 0.7]) {
      for (const n of [1, 2, 5, 40]) expect(cappedInformation(n, rho)).toBeCloseTo(equicorrelatedInformation(n, rho), 12);
      expect(cappedInformation(1e6, rho)).toBeLessThan(1 / rho);
    }
    expect(cappedInformation(7, 0)).toBe(7);
    expect(cappedInformation(0.4, 0.5)).toBe(0.4);
  });
});

describe("ellipse scale", () => {
  it("scales the covariance, not the mean", () => {
    const g = { px: Float64Array.from([0, 2, 0]), py: Float64Array.from([0, 0, 1]) } as unknown as Graph;
    const w = Float64Array.from([0.5, 0.25, 0.25]);
    const live = Int32Array.from([0, 1, 2]);
    const one = gaussianSummary(g, w, live, 0.1);
    const four = gaussianSummary(g, w, live, 0.1, 20, 4);
    expect(four.x).toBeCloseTo(one.x, 12);
    expect(four.y).toBeCloseTo(one.y, 12);
    expect(four.cxx).toBeCloseTo(4 * one.cxx, 12);
    expect(four.cxy).toBeCloseTo(4 * one.cxy, 12);
    expect(four.sigma_major_m).toBeCloseTo(2 * one.sigma_major_m, 12);
    expect(four.angle_deg).toBeCloseTo(one.angle_deg, 9);
  });
});
