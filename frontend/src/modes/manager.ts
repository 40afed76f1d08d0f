/** Holds the current mode; refuses illegal transitions; keeps `state.mode` in step. */
import { setMode } from "../actions/editor";
import type { ModeName } from "../state/editor";
import { modeBrowse } from "./browse";
import { modeDrag } from "./drag";
import { modeSelectRange } from "./selectRange";
import { type DragStart, type Mode, type ModeContext, canTransition } from "./types";

export class ModeManager {
  private current: Mode;
  private readonly modes: Record<ModeName, Mode> = {
    browse: modeBrowse(),
    drag: modeDrag(),
    "select-range": modeSelectRange(),
  };

  constructor(private readonly ctx: Omit<ModeContext, "switchTo">) {
    this.current = this.modes.browse;
    this.current.enter(this.context());
  }

  get name(): ModeName {
    return this.current.name;
  }

  /** Switch mode; returns false (and stays) when the transition is not allowed. */
  switchTo(name: ModeName, arg?: DragStart): boolean {
    if (name === this.current.name) return true;
    if (!canTransition(this.current.name, name)) return false;
    this.current.exit();
    this.current = this.modes[name];
    this.ctx.store.update((s) => setMode(s, name));
    this.current.enter(this.context(), arg);
    return true;
  }

  destroy(): void {
    this.current.exit();
  }

  private context(): ModeContext {
    return { ...this.ctx, switchTo: (n, a) => void this.switchTo(n, a) };
  }
}
