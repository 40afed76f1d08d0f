import type { Map as MlMap } from "maplibre-gl";
import type { EditorState, ModeName } from "../state/editor";
import type { Store } from "../state/store";
import type { LonLat } from "../state/types";

/** What modes may use: the map to listen on, the store to stage into, and commit hooks. */
export interface ModeContext {
  map: MlMap;
  store: Store<EditorState>;
  /** A drag ended at `lonlat`: check the rules and commit one edit (or show the refusal). */
  commitMove(index: number, lonlat: LonLat): void;
  /** A range was picked in select-range mode. */
  commitRange(from: number, to: number): void;
  openImages(index: number): void;
  switchTo(mode: ModeName, arg?: DragStart): void;
}

export interface DragStart {
  index: number;
  lonlat: LonLat;
  touch: boolean;
}

/** A mode switches a set of behaviours on (enter) and off (exit), as Rapid's modes do. */
export interface Mode {
  readonly name: ModeName;
  enter(ctx: ModeContext, arg?: DragStart): void;
  exit(): void;
}

/** Legal transitions; anything else is refused. */
export const TRANSITIONS: Record<ModeName, ModeName[]> = {
  browse: ["drag", "select-range"],
  drag: ["browse"],
  "select-range": ["browse"],
};

export function canTransition(from: ModeName, to: ModeName): boolean {
  return TRANSITIONS[from].includes(to);
}
