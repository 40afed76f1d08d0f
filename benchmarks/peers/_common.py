"""What both peer scripts do the same way: read the CSV and edits, go to a local ENU frame
and back, write the CSV (pyarrow, as a competent script would)."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

A = 6378137.0
F = 1 / 298.257223563
E2 = F * (2 - F)


def read_table(path: str) -> pa.Table:
    return pacsv.read_csv(path)


def col(table: pa.Table, name: str) -> np.ndarray:
    return table.column(name).to_numpy(zero_copy_only=False).astype(float)


def read_edits(path: str) -> list[tuple[float, float, float]]:
    with open(path) as fh:
        return [(e["t"], e["lat"], e["lon"]) for e in json.load(fh).get("edits", [])]


def to_ecef(lat: np.ndarray, lon: np.ndarray, alt: np.ndarray) -> np.ndarray:
    la, lo = np.radians(lat), np.radians(lon)
    n = A / np.sqrt(1 - E2 * np.sin(la) ** 2)
    return np.column_stack([(n + alt) * np.cos(la) * np.cos(lo), (n + alt) * np.cos(la) * np.sin(lo),
                            (n * (1 - E2) + alt) * np.sin(la)])


def enu_basis(lat0: float, lon0: float) -> np.ndarray:
    la, lo = np.radians(lat0), np.radians(lon0)
    return np.array([[-np.sin(lo), np.cos(lo), 0.0],
                     [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                     [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])


class Frame:
    """Local ENU about the first sample."""

    def __init__(self, lat0: float, lon0: float, alt0: float):
        self.o = to_ecef(np.array([lat0]), np.array([lon0]), np.array([alt0]))[0]
        self.R = enu_basis(lat0, lon0)

    def enu(self, lat, lon, alt) -> np.ndarray:
        return (to_ecef(np.asarray(lat), np.asarray(lon), np.asarray(alt)) - self.o) @ self.R.T

    def geodetic(self, enu: np.ndarray):
        x, y, z = (enu @ self.R + self.o).T
        lon = np.arctan2(y, x)
        p = np.hypot(x, y)
        lat = np.arctan2(z, p * (1 - E2))
        for _ in range(3):
            n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
            alt = p / np.cos(lat) - n
            lat = np.arctan2(z, p * (1 - E2 * n / (n + alt)))
        n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
        return np.degrees(lat), np.degrees(lon), p / np.cos(lat) - n


def edit_indices(t: np.ndarray, edits) -> np.ndarray:
    """The sample each edit names (its time, to the millisecond)."""
    idx = np.searchsorted(t, [e[0] for e in edits]).clip(0, len(t) - 1)
    prev = (idx - 1).clip(0)
    closer = np.abs(t[prev] - [e[0] for e in edits]) < np.abs(t[idx] - [e[0] for e in edits])
    return np.where(closer, prev, idx)


def write_table(table: pa.Table, lat, lon, alt, path: str, q: np.ndarray | None = None) -> None:
    cols = {"lat": lat, "lon": lon, "alt": alt}
    if q is not None:
        cols.update(qw=q[:, 0], qx=q[:, 1], qy=q[:, 2], qz=q[:, 3])
    for name, values in cols.items():
        table = table.set_column(table.schema.get_field_index(name), name, pa.array(values))
    pacsv.write_csv(table, path)
