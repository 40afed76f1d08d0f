import { describe, expect, it } from "vitest";
import { NUDGE_FAR_M, NUDGE_M, editorCommand, nudgeVector } from "../src/behaviors/keyboard";

const key = (k: string, mods: Partial<{ ctrlKey: boolean; metaKey: boolean; shiftKey: boolean }> = {}) => ({ key: k, ctrlKey: false, metaKey: false, shiftKey: false, ...mods });
const browse = { conflict: null, mode: "browse" as const, selected: null };
const selected = { ...browse, selected: 10 };

describe("editorCommand", () => {
  it("maps undo, redo and their modifiers", () => {
    expect(editorCommand(key("z", { ctrlKey: true }), browse)).toBe("undo");
    expect(editorCommand(key("Z", { ctrlKey: true, shiftKey: true }), browse)).toBe("redo");
    expect(editorCommand(key("y", { metaKey: true }), browse)).toBe("redo");
    expect(editorCommand(key("s", { ctrlKey: true }), browse)).toBeNull();
  });

  it("maps the single keys", () => {
    expect(editorCommand(key("."), browse)).toBe("next");
    expect(editorCommand(key(","), browse)).toBe("previous");
    expect(editorCommand(key("Delete"), browse)).toBe("toggle-delete");
    expect(editorCommand(key("Escape"), browse)).toBe("escape");
    expect(editorCommand(key("q"), browse)).toBeNull();
  });

  it("does nothing during a conflict or a drag", () => {
    expect(editorCommand(key("z", { ctrlKey: true }), { conflict: { baseRevision: 1, currentRevision: 2 }, mode: "browse", selected: null })).toBeNull();
    expect(editorCommand(key("."), { conflict: null, mode: "drag", selected: 10 })).toBeNull();
  });

  it("arrows nudge the selected keyframe (Shift: farther) and leave the map its pan otherwise", () => {
    expect(editorCommand(key("ArrowRight"), selected)).toBe("nudge-east");
    expect(editorCommand(key("ArrowUp", { shiftKey: true }), selected)).toBe("nudge-north-far");
    expect(nudgeVector("nudge-west")).toEqual([-NUDGE_M, 0]);
    expect(nudgeVector("nudge-south-far")).toEqual([0, -NUDGE_FAR_M]);
    expect(nudgeVector("undo")).toBeNull();
    expect(editorCommand(key("ArrowLeft"), browse)).toBeNull();
    expect(editorCommand(key("ArrowDown"), { ...selected, mode: "drag" })).toBeNull();
  });
});
