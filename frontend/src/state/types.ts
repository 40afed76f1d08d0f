/**
 * The editor's data model. Pure data: nothing here knows about MapLibre, the DOM or HTTP.
 * Positions are WGS84 `[lon, lat]` in degrees (GeoJSON order); distances in metres.
 */

export type LonLat = readonly [number, number];

/** Editing rules in force for a run (mirrors `posefix.core.rules.EditRules`). */
export interface EditRules {
  /** Only every `every_n`-th keyframe (index % every_n == 0) may be moved. */
  every_n: number;
  /** An edit locks this many keyframes next to it (see `lock_direction`). */
  lock_n: number;
  /** Which neighbours an edit locks: those after it, or on both sides. */
  lock_direction: "forward" | "both";
  /** A keyframe may be moved at most this far from its reported position (m); always finite (1 m to 10 km). */
  max_move_m: number;
  /** A move that reverses the order of poses: "refuse" it, or accept it with a "flag". */
  order_rule: "refuse" | "flag";
  /** What deletion does: "remove" the keyframe or "flag" it. */
  deleted: "remove" | "flag";
}

/** One keyframe of the loaded revision, as the server sent it. */
export interface Keyframe {
  index: number;
  t_s: number;
  /** Position in the loaded revision. */
  lonlat: LonLat;
  /** Position reported by the recorder (GNSS), the reference for `max_move_m`. */
  reported: LonLat;
  heading_deg: number;
  adjustable: boolean;
  locked: boolean;
  edited: boolean;
  deleted: boolean;
  flagged: boolean;
  images: string[];
  correction_m: number;
  /** Horizontal 1-sigma of the correction the run's held-out edits predict (m); null with fewer than three edits. */
  sigma_m: number | null;
}

/** The engine's GNSS drift estimate (bias of GNSS against the operators' edits). */
export interface Drift {
  /** Horizontal size of the mean offset (m), null when not estimable. */
  offset_m: number | null;
  spread_m: number | null;
  /** Largest bias along the run (m). */
  max_bias_m: number | null;
  detected: boolean | null;
  n_edits: number | null;
  /** The model the run's own held-out edits chose (gnss, plain, relative, naive, prior), its
   * cross-validated RMSE at the edits (m) and the RMSE along the run it predicts (m). */
  model: string | null;
  cv_rmse_m: number | null;
  predicted_rmse_m: number | null;
}

/** A run's keyframes at one revision: what the editor edits against. */
export interface RunDoc {
  runId: string;
  name: string;
  revision: number;
  rules: EditRules;
  keyframes: Keyframe[];
  drift: Drift | null;
  /** Positions the earlier revisions' moves put keyframes at (the rules' `edited_before`). */
  baseMoves: ReadonlyMap<number, LonLat>;
}

/** The operator's unsaved edits: what one submit sends. Immutable; replaced on change. */
export interface Edits {
  /** keyframe index -> proposed position. */
  readonly moves: ReadonlyMap<number, LonLat>;
  readonly deleted: ReadonlySet<number>;
  readonly accept: boolean;
  /** Moves accepted from map-matching suggestions (sent as kind "suggestion"); see src/maps. */
  readonly suggested?: ReadonlySet<number>;
}

export type RefusalReason =
  | "out_of_range"
  | "duplicate"
  | "deleted"
  | "not_adjustable"
  | "locked"
  | "too_far"
  | "order_reversed"
  | string;

export interface Refusal {
  index: number;
  reason: RefusalReason;
  message: string;
}

export const EMPTY_EDITS: Edits = Object.freeze({
  moves: new Map<number, LonLat>(),
  deleted: new Set<number>(),
  accept: false,
});

/** A map-matching suggestion: where the street map would put keyframe `index`. */
export interface Suggestion {
  index: number;
  lonlat: LonLat;
  /** Distance from the keyframe's position at the matched revision (m). */
  moved_m: number;
  off_road: boolean;
  /** 1σ of the match (m). */
  sigma_m: number;
  adjustable: boolean;
}

export type SuggestionsState =
  | { kind: "idle" }
  | { kind: "loading" }
  | { kind: "error"; message: string }
  | SuggestionsReady;

/** Suggestions on screen: one is focused (a click or the list picks it; accepting is explicit). */
export interface SuggestionsReady {
  kind: "ready";
  revision: number;
  items: Suggestion[];
  offRoad: number;
  timeMs: number;
  /** Which matcher answered: "roads" (the road network) or "grid" (the drivable-area grid). */
  matcher: string;
  /** Keyframe index of the focused suggestion, or null. */
  focus: number | null;
  /** Suggestions the operator passed over (not accepted, left out of "Accept all"). */
  skipped: ReadonlySet<number>;
  /** Whether the suggestion layer and its keys are on. */
  shown: boolean;
}
