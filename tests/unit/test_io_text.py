"""Column-wise text rendering: orjson's float text must be Arrow's wherever it is used."""

from __future__ import annotations

import numpy as np

from posefix.io._text import _arrow_text, _as_text_column, render_rows


def test_float_text_is_arrows_across_magnitudes_and_specials():
    rng = np.random.default_rng(5)
    v = rng.uniform(-1, 1, 200_000) * 10.0 ** rng.uniform(-9, 17, 200_000)
    edges = np.array([1e-5, np.nextafter(1e-5, 0), np.nextafter(1e10, 0), 1e10, 1e10 + 0.5, 9999999999.5,
                      0.0, -0.0, 1.0, -3.0, 1e15, 4.5e15 + 0.5, 1e-7, np.nan, np.inf, -np.inf, 60.17, 1.7e9 + 0.01])
    for values in (np.concatenate([v, edges, -edges]), 60 + rng.random(1000) * 1e-3, edges):
        assert _as_text_column(values, "null").to_pylist() == _arrow_text(values, "null").to_pylist()


def test_rows_in_threaded_chunks_keep_order():
    n = 200_001  # several chunks
    t = np.arange(n) * 0.25 + 0.125
    body = render_rows([t, ",", [str(i) for i in range(n)], "\n"])
    lines = body.decode().splitlines()
    assert len(lines) == n and lines[0] == "0.125,0" and lines[-1] == f"{float(t[-1])!r},{n - 1}"
