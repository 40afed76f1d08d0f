"""Naive correction: every sample moved by the edits' offsets, interpolated linearly in time
(held constant before the first and after the last edit)."""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from _common import Frame, col, edit_indices, read_edits, read_table, write_table  # noqa: E402


def main(src: str, edits_path: str, out: str) -> None:
    table = read_table(src)
    t, lat, lon, alt = (col(table, c) for c in ("t", "lat", "lon", "alt"))
    frame = Frame(lat[0], lon[0], alt[0])
    p = frame.enu(lat, lon, alt)
    edits = read_edits(edits_path)
    if edits:
        idx = edit_indices(t, edits)
        target = frame.enu([e[1] for e in edits], [e[2] for e in edits], alt[idx])
        off = target - p[idx]
        p = p + np.column_stack([np.interp(t, t[idx], off[:, k]) for k in range(3)])
    write_table(table, *frame.geodetic(p), out)


if __name__ == "__main__":
    main(*sys.argv[1:4])
