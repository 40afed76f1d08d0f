"""Small runs and paths shared by the I/O, simulation and CLI tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posefix.core.geodesy import enu_to_geodetic
from posefix.core.run import PoseRun

REPO = Path(__file__).resolve().parents[2]


def comma2k19_segment() -> Path:
    """The comma2k19 example segment shipped in data/ (see data/NOTICE.md)."""
    return REPO / "data" / "comma2k19"


def osm_extract() -> Path:
    return REPO / "data" / "osm" / "helsinki.osm.pbf"


def yaw_quat(yaw_rad: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(yaw_rad / 2), np.zeros_like(yaw_rad), np.zeros_like(yaw_rad), np.sin(yaw_rad / 2)])


def small_run(n: int = 50, seed: int = 0, gnss: bool = True, images: bool = True, extra: bool = True,
              origin=(60.17, 24.94, 20.0), t0: float = 1_700_000_000.0, rate_hz: float = 10.0) -> PoseRun:
    """A gently curving 10 m/s drive with orientation, raw GNSS (some gaps), images, extras."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate_hz
    yaw = 0.3 + 0.02 * np.arange(n)
    step = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros(n)]) * (10.0 / rate_hz)
    p = np.cumsum(step, axis=0)
    lat, lon, alt = enu_to_geodetic(p, origin)
    kw = {}
    if gnss:
        g = p + rng.normal(0, 3.0, p.shape)
        glat, glon, galt = enu_to_geodetic(g, origin)
        glat[::7] = np.nan
        glon[::7] = np.nan
        galt[::7] = np.nan
        kw.update(gnss_lat_deg=glat, gnss_lon_deg=glon, gnss_alt_m=galt)
    if images:
        kw["images"] = [f"img_{i:04d}.jpg;side_{i:04d}.jpg" if i % 5 == 0 else "" for i in range(n)]
    if extra:
        kw["extra"] = {"speed_mps": np.full(n, 10.0), "note": np.array([f"a,b {i}" for i in range(n)], dtype=object)}
    return PoseRun(t_s=t, lat_deg=lat, lon_deg=lon, alt_m=alt, q_body_to_enu_wxyz=yaw_quat(yaw), source="small", **kw)


def leftovers(folder: Path) -> list[str]:
    """Temporary files a failed atomic write could have left."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and p.name.endswith(".tmp"))
