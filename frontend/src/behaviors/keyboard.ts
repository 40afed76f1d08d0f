/**
 * The editor's keyboard behaviour: which command a key press means (a pure function, unit
 * tested), and a window listener that runs it. Keys typed into form fields are left alone,
 * and nothing runs while a conflict is shown or a drag is in progress.
 */
import type { EditorState } from "../state/editor";

/** Arrow keys move the selected keyframe: 0.5 m a press, 5 m with Shift. */
export type NudgeCommand = `nudge-${"east" | "west" | "north" | "south"}${"" | "-far"}`;

const NUDGES = ["nudge-east", "nudge-west", "nudge-north", "nudge-south", "nudge-east-far", "nudge-west-far", "nudge-north-far", "nudge-south-far"] as const satisfies readonly NudgeCommand[];

export const EDITOR_COMMANDS = [
  "undo", "redo", "next", "previous", "next-adjustable", "toggle-delete", "delete-range",
  "images", "ghost", "fit", "unmove", "history", "escape",
  "suggestion-accept", "suggestion-skip", "suggestion-next", "suggestion-previous",
  ...NUDGES,
] as const;
export type EditorCommand = (typeof EDITOR_COMMANDS)[number];

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

/**
 * Every editor shortcut in words: the help overlay and the side panel list this table, and a
 * unit test checks each entry against `editorCommand`, so the help cannot drift from the keys.
 * `when` names a condition the keys need beyond the editor being open.
 */
export const EDITOR_SHORTCUTS: { keys: string[]; command: EditorCommand; what: string; when?: "suggestions" | "selected" }[] = [
  { keys: [".", "n"], command: "next", what: "Select the next keyframe" },
  { keys: [",", "p"], command: "previous", what: "Select the previous keyframe" },
  { keys: ["A"], command: "next-adjustable", what: "Select the next adjustable keyframe" },
  ...(Object.entries(ARROWS).flatMap(([key, dir]) => [
    { keys: [key], command: `nudge-${dir}` as NudgeCommand, what: `Nudge the selected keyframe ${NUDGE_M} m ${dir}`, when: "selected" as const },
    { keys: [`Shift+${key}`], command: `nudge-${dir}-far` as NudgeCommand, what: `Nudge it ${NUDGE_FAR_M} m ${dir}`, when: "selected" as const },
  ])),
  { keys: ["Ctrl+Z"], command: "undo", what: "Undo the last step" },
  { keys: ["Ctrl+Shift+Z", "Ctrl+Y"], command: "redo", what: "Redo" },
  { keys: ["Delete", "Backspace"], command: "toggle-delete", what: "Mark the selected keyframe for deletion, or restore it" },
  { keys: ["R"], command: "delete-range", what: "Delete a range: click its first and last keyframe" },
  { keys: ["U"], command: "unmove", what: "Put the selected keyframe back (drop its move)" },
  { keys: ["I"], command: "images", what: "Images of the selected keyframe" },
  { keys: ["G"], command: "ghost", what: "Show or hide the loaded revision (ghost)" },
  { keys: ["F"], command: "fit", what: "Zoom to the whole run" },
  { keys: ["H"], command: "history", what: "History: revisions, compare, revert" },
  { keys: ["Escape"], command: "escape", what: "Cancel: clear the selection, close panels" },
  { keys: ["Enter"], command: "suggestion-accept", what: "Accept the picked suggestion", when: "suggestions" },
  { keys: ["S"], command: "suggestion-skip", what: "Skip the picked suggestion, pick the next", when: "suggestions" },
  { keys: ["]"], command: "suggestion-next", what: "Pick the next suggestion", when: "suggestions" },
  { keys: ["["], command: "suggestion-previous", what: "Pick the previous suggestion", when: "suggestions" },
];

/** "Ctrl+Shift+Z" -> the key press it names (for the table above and its test). */
export function parseKeys(keys: string): KeyLike {
  const parts = keys.split("+");
  const key = parts.length > 1 && parts[parts.length - 1] === "" ? "+" : parts[parts.length - 1];
  return { key, ctrlKey: parts.includes("Ctrl"), metaKey: parts.includes("Meta"), shiftKey: parts.includes("Shift") };
}

export interface KeyLike {
  key: string;
  ctrlKey: boolean;
  metaKey: boolean;
  shiftKey: boolean;
}

/** The command for a key press in state `s`, or null when the key is not the editor's. */
export function editorCommand(e: KeyLike, s: Pick<EditorState, "conflict" | "mode" | "selected"> & Partial<Pick<EditorState, "suggestions" | "doc">>): EditorCommand | null {
  if (s.conflict || s.mode === "drag") return null;
  const g = s.suggestions;
  if (g?.kind === "ready" && g.shown && s.doc?.revision === g.revision && !e.ctrlKey && !e.metaKey) {
    if (e.key === "Enter") return "suggestion-accept";
    if (e.key === "s" || e.key === "S") return "suggestion-skip";
    if (e.key === "]") return "suggestion-next";
    if (e.key === "[") return "suggestion-previous";
  }
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

/** Keys pressed in an open dialog (image viewer, help) belong to it; Enter on a control presses it. */
function ownedElsewhere(e: KeyboardEvent): boolean {
  const el = e.target as HTMLElement | null;
  if (!el || typeof el.closest !== "function") return false;
  if (el.closest("dialog[open]")) return true;
  return e.key === "Enter" && !!el.closest("button, a, summary");
}

/** Listen on `target` (capture phase); `run` performs a command. Returns the cleanup. */
export function installEditorKeys(target: Window, state: () => EditorState, run: (c: EditorCommand) => void): () => void {
  const onKey = (e: KeyboardEvent) => {
    if (typingInto(e.target) || ownedElsewhere(e)) return;
    const c = editorCommand(e, state());
    if (c === null) return;
    run(c);
    e.preventDefault();
    e.stopPropagation();
  };
  target.addEventListener("keydown", onKey, true);
  return () => target.removeEventListener("keydown", onKey, true);
}
