/**
 * Small-distance geodesy on the WGS84 ellipsoid, enough for edit rules (moves of metres to
 * hundreds of metres). Local east/north offsets use the meridional (M) and prime-vertical (N)
 * radii of curvature at the mean latitude:
 *   dE = N cos(phi) dlambda,  dN = M dphi,
 *   M = a (1 - e^2) / (1 - e^2 sin^2 phi)^(3/2),  N = a / sqrt(1 - e^2 sin^2 phi).
 */
import type { LonLat } from "../state/types";

const A_M = 6378137.0;
const F = 1 / 298.257223563;
const E2 = F * (2 - F);
const DEG = Math.PI / 180;

/** East/north offset (m) of `to` from `from`, both [lon, lat] degrees. */
export function offsetEnM(from: LonLat, to: LonLat): [number, number] {
  const latMeanRad = ((from[1] + to[1]) / 2) * DEG;
  const s = Math.sin(latMeanRad);
  const w = Math.sqrt(1 - E2 * s * s);
  const nM = A_M / w;
  const mM = (A_M * (1 - E2)) / (w * w * w);
  return [(to[0] - from[0]) * DEG * nM * Math.cos(latMeanRad), (to[1] - from[1]) * DEG * mM];
}

/** The position `east_m`/`north_m` metres from `from` (the inverse of `offsetEnM` for small offsets). */
export function offsetLonLat(from: LonLat, eastM: number, northM: number): [number, number] {
  const s = Math.sin(from[1] * DEG);
  const w = Math.sqrt(1 - E2 * s * s);
  const nM = A_M / w;
  const mM = (A_M * (1 - E2)) / (w * w * w);
  return [from[0] + eastM / (nM * Math.cos(from[1] * DEG)) / DEG, from[1] + northM / mM / DEG];
}

/** Horizontal distance (m) between two [lon, lat] positions. */
export function distanceM(a: LonLat, b: LonLat): number {
  const [e, n] = offsetEnM(a, b);
  return Math.hypot(e, n);
}

/** WGS84 geodetic (lon, lat degrees; h metres) to ECEF (m). */
export function ecefM(lonDeg: number, latDeg: number, hM = 0): [number, number, number] {
  const lam = lonDeg * DEG;
  const phi = latDeg * DEG;
  const s = Math.sin(phi);
  const nM = A_M / Math.sqrt(1 - E2 * s * s);
  const c = Math.cos(phi);
  return [(nM + hM) * c * Math.cos(lam), (nM + hM) * c * Math.sin(lam), (nM * (1 - E2) + hM) * s];
}

/**
 * A local east/north projection (m) about `origin`: the exact ENU tangent plane at height 0,
 *   [e, n] = R(lon0, lat0) (x_ecef - x0_ecef), dropping up.
 */
export function enuProjector(origin: LonLat): (p: LonLat) => [number, number] {
  const [x0, y0, z0] = ecefM(origin[0], origin[1]);
  const lam = origin[0] * DEG;
  const phi = origin[1] * DEG;
  const sl = Math.sin(lam), cl = Math.cos(lam), sp = Math.sin(phi), cp = Math.cos(phi);
  return (p) => {
    const [x, y, z] = ecefM(p[0], p[1]);
    const dx = x - x0, dy = y - y0, dz = z - z0;
    return [-sl * dx + cl * dy, -sp * cl * dx - sp * sl * dy + cp * dz];
  };
}
