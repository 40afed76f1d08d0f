/**
 * Error of a track at a walk's surveyed waypoints (posefix.mapmatch.evaluate): the track
 * interpolated linearly at each waypoint's time (held before the first and after the last
 * row), its distance to the waypoint.
 */
import { interp } from "./sensors";

export function waypointErrors(t: ArrayLike<number>, x: ArrayLike<number>, y: ArrayLike<number>, waypoints: { t_ms: number; x_m: number; y_m: number }[]): number[] {
  return waypoints.map((w) => Math.hypot(interp(w.t_ms, t, x) - w.x_m, interp(w.t_ms, t, y) - w.y_m));
}
