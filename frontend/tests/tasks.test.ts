import { describe, expect, it } from "vitest";
import { fmtRemaining, fmtReward, leaseUrgent, remainingAt, requirementText, trackColour, worstKeyframes } from "../src/tasks/format";

describe("lease timer", () => {
  it("formats minutes and hours", () => {
    expect(fmtRemaining(600)).toBe("10:00");
    expect(fmtRemaining(59.9)).toBe("00:59");
    expect(fmtRemaining(3725)).toBe("1:02:05");
    expect(fmtRemaining(0)).toBe("expired");
    expect(fmtRemaining(-3)).toBe("expired");
    expect(fmtRemaining(Number.NaN)).toBe("expired");
  });
  it("counts down on the browser clock", () => {
    expect(remainingAt(300, 1_000, 61_000)).toBe(240);
  });
  it("warns in the last fifth, at least the last minute", () => {
    expect(leaseUrgent(100, 600)).toBe(true);
    expect(leaseUrgent(121, 600)).toBe(false);
    expect(leaseUrgent(59, 120)).toBe(true);
  });
});

describe("review helpers", () => {
  it("orders the worst keyframes", () => {
    expect(worstKeyframes([1, 9, 3, 9, 0.5], 3, 0.9)).toEqual([[1, 9], [3, 9], [2, 3]]);
  });
  it("cycles colours", () => {
    expect(trackColour(0)).not.toBe(trackColour(1));
    expect(trackColour(7)).toBe(trackColour(0));
  });
  it("says requirements and rewards in words", () => {
    expect(requirementText({ qualification: "approved_count", comparator: "ge", value: 5 })).toBe("approved assignments (count) at least 5");
    expect(requirementText({ qualification: "level", comparator: "in", value: [1, 2] })).toBe("level is one of 1, 2");
    expect(fmtReward(50, "EUR")).toBe("0.50 EUR");
  });
});
