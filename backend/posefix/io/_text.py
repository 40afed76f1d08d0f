"""Build large text outputs column-wise in C++ (pyarrow), not per row in Python.

``render_rows(pieces)`` takes literal strings and per-row columns (float arrays, string
lists) and returns the bytes of every row's pieces concatenated, rows one after another.
Floats are formatted in shortest round-trip form by Arrow; NaN becomes ``nan_text``.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np

Piece = Union[str, np.ndarray, list]


def _as_text_column(values, nan_text: str):
    import pyarrow as pa
    import pyarrow.compute as pc

    if isinstance(values, np.ndarray) and values.dtype.kind in "fiu":
        arr = pa.array(np.ascontiguousarray(values, dtype=float))
        text = pc.cast(arr, pa.large_string())  # 64-bit offsets: outputs may pass 2 GB
        nan = np.isnan(values.astype(float, copy=False))
        if nan.any():
            text = pc.if_else(pa.array(nan), pa.scalar(nan_text, pa.large_string()), text)
        return text
    return pa.array(["" if v is None else str(v) for v in values], type=pa.large_string())


def render_rows(pieces: Sequence[Piece], nan_text: str = "") -> bytes:
    """Concatenate, for each row, the pieces (literals repeated on every row)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    n = None
    cols = []
    for p in pieces:
        if isinstance(p, str):
            cols.append(pa.scalar(p, pa.large_string()))
        else:
            col = _as_text_column(p, nan_text)
            n = len(col) if n is None else n
            if len(col) != n:
                raise ValueError("columns of different lengths")
            cols.append(col)
    if n is None:
        raise ValueError("render_rows needs at least one column")
    if n == 0:
        return b""
    joined = pc.binary_join_element_wise(*cols, pa.scalar("", pa.large_string()))
    if isinstance(joined, pa.ChunkedArray):
        joined = joined.combine_chunks()
    offsets = np.frombuffer(joined.buffers()[1], dtype=np.int64)[joined.offset: joined.offset + n + 1]
    data = joined.buffers()[2]
    return data.to_pybytes()[offsets[0]: offsets[-1]]


def escape_xml_text(values: list[str]) -> list[str]:
    from xml.sax.saxutils import escape

    return [escape(v, {'"': "&quot;"}) for v in values]
