/**
 * The editor's keyboard behaviour: which command a key press means (a pure function, unit
 * tested), and a window listener that runs it. Keys typed into form fields are left alone,
 * and nothing runs while a conflict is shown or a drag is in progress.
 */
import type { EditorState } from "../state/editor";

export type EditorCommand =
  | "undo" | "redo" | "next" | "previous" | "next-adjustable" | "toggle-delete" | "delete-range"
  | "images" | "ghost" | "fit" | "unmove" | "history" | "escape" | NudgeCommand;

/** Arrow keys move the selected keyframe: 0.5 m a press, 5 m with Shift. */
export type NudgeCommand = `nudge-${"east" | "west" | "north" | "south"}${"" | "-far"}`;

export const NUDGE_M = 0.5;
export const NUDGE_FAR_M = 5;

const ARROWS: Record<string, "east" | "west" | "north" | "south"> = { ArrowRight: "east", ArrowLeft: "west", ArrowUp: "north", ArrowDown: "south" };

const DIRECTIONS: Record<string, [number, number]> = { east: [1, 0], west: [-1, 0], north: [0, 1], south: [0, -1] };

/** East/north metres of a nudge command, or null for any other command. */
export function nudgeVector(c: EditorCommand): [number, number] | null {
  const m = /^nudge-(east|west|north|south)(-far)?$/.exec(c);
  if (!m) return null;
  const d = m[2] ? NUDGE_FAR_M : NUDGE_M;
  const [e, n] = DIRECTIONS[m[1]];
  return [e * d, n * d];
}

export interface KeyLike {
  key: string;
  ctrlKey: boolean;
  metaKey: boolean;
  shiftKey: boolean;
}

/** The command for a key press in state `s`, or null when the key is not the editor's. */
export function editorCommand(e: KeyLike, s: Pick<EditorState, "conflict" | "mode" | "selected">): EditorCommand | null {
  if (s.conflict || s.mode === "drag") return null;
  const k = e.key;
  // With nothing selected the arrows are the map's own (pan).
  if (k in ARROWS) return s.selected === null || e.ctrlKey || e.metaKey ? null : `nudge-${ARROWS[k]}${e.shiftKey ? "-far" : ""}`;
  if (e.ctrlKey || e.metaKey) {
    if (k === "z" || k === "Z") return e.shiftKey ? "redo" : "undo";
    if (k === "y" || k === "Y") return "redo";
    return null;
  }
  switch (k) {
    case ".": case "n": return "next";
    case ",": case "p": return "previous";
    case "a": case "A": return "next-adjustable";
    case "Delete": case "Backspace": return "toggle-delete";
    case "r": case "R": return "delete-range";
    case "i": case "I": return "images";
    case "g": case "G": return "ghost";
    case "f": case "F": return "fit";
    case "u": case "U": return "unmove";
    case "h": case "H": return "history";
    case "Escape": return "escape";
    default: return null;
  }
}

function typingInto(t: EventTarget | null): boolean {
  const el = t as HTMLElement | null;
  return !!el && (el.tagName === "INPUT" || el.tagName === "TEXTAREA" || el.tagName === "SELECT" || el.isContentEditable);
}

/** Listen on `target` (capture phase); `run` performs a command. Returns the cleanup. */
export function installEditorKeys(target: Window, state: () => EditorState, run: (c: EditorCommand) => void): () => void {
  const onKey = (e: KeyboardEvent) => {
    if (typingInto(e.target)) return;
    const c = editorCommand(e, state());
    if (c === null) return;
    run(c);
    e.preventDefault();
    e.stopPropagation();
  };
  target.addEventListener("keydown", onKey, true);
  return () => target.removeEventListener("keydown", onKey, true);
}
