"""Parquet and Arrow IPC run files: exact round trips with units in the schema, the same
checks as the CSV reader (file, row, field named), and the CSV writer's threaded slices."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc
import pyarrow.parquet as pq
import pytest

from posefix.io import RunFormatError, read_run, write_run
from posefix.io.columnar import run_to_arrow

from .io_helpers import leftovers, small_run

FIELDS = ("t_s", "lat_deg", "lon_deg", "alt_m", "gnss_lat_deg", "gnss_lon_deg", "gnss_alt_m")


@pytest.mark.parametrize("ext", ["parquet", "arrow", "feather"])
def test_round_trip_is_exact_with_units_in_the_schema(tmp_path: Path, ext: str) -> None:
    run = small_run()
    path = tmp_path / f"run.{ext}"
    write_run(run, path)
    back = read_run(path)
    for name in FIELDS:
        assert np.array_equal(getattr(back, name), getattr(run, name), equal_nan=True), name
    # every reader re-normalises the quaternions: the last bit may move
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-15
    assert back.images == run.images
    assert list(back.extra) == ["speed_mps", "note"]
    assert back.extra["note"].tolist() == run.extra["note"].tolist()
    assert np.array_equal(back.extra["speed_mps"], run.extra["speed_mps"])
    schema = pq.read_schema(path) if ext == "parquet" else ipc.open_file(pa.memory_map(str(path))).schema
    assert schema.field("t").metadata == {b"unit": b"s"}
    assert schema.field("lat").metadata == {b"unit": b"deg"}
    assert schema.field("alt").metadata == {b"unit": b"m"}
    assert json.loads(schema.metadata[b"posefix"])["layout"] == "posefix-run"
    assert leftovers(tmp_path) == []


def test_a_hop_through_parquet_and_arrow_changes_no_csv_byte(tmp_path: Path) -> None:
    run = small_run(n=300)
    write_run(run, tmp_path / "a.csv")
    write_run(read_run(tmp_path / "a.csv"), tmp_path / "direct.csv")
    write_run(read_run(tmp_path / "a.csv"), tmp_path / "b.parquet")
    write_run(read_run(tmp_path / "b.parquet"), tmp_path / "c.arrow")
    write_run(read_run(tmp_path / "c.arrow"), tmp_path / "d.csv")
    assert (tmp_path / "direct.csv").read_bytes() == (tmp_path / "d.csv").read_bytes()


def _table_with(run, **changes):
    table = run_to_arrow(run)
    for name, values in changes.items():
        i = table.schema.get_field_index(name)
        table = table.drop_columns([name]) if values is None else table.set_column(i, name, values)
    return table


@pytest.mark.parametrize("changes, line, field, fragment", [
    ({"lat": None}, None, "lat", "missing required column"),
    ({"qw": None}, None, "qw", "orientation needs all of"),
    ({"t": pa.array(["a"] * 50)}, None, "t", "is not a number"),
    ({"alt": pa.array([1.0] * 7 + [None] + [1.0] * 42)}, 8, "alt", "missing"),
    ({"lat": pa.array([60.0] * 11 + [91.0] + [60.0] * 38)}, 12, "lat", "outside [-90, 90]"),
    ({"t": pa.array(np.r_[np.arange(20.0), 5.0, np.arange(21.0, 50.0)])}, 21, "t", "not strictly increasing"),
])
def test_bad_columns_name_file_row_and_field(tmp_path: Path, changes, line, field, fragment) -> None:
    table = _table_with(small_run(), **changes)
    for path in (tmp_path / "bad.parquet", tmp_path / "bad.arrow"):
        if path.suffix == ".parquet":
            pq.write_table(table, path)
        else:
            with ipc.new_file(str(path), table.schema) as w:
                w.write_table(table)
        with pytest.raises(RunFormatError) as err:
            read_run(path)
        e = err.value
        assert (e.file, e.line, e.field) == (str(path), line, field), str(e)
        assert fragment in e.message


def test_a_file_that_is_not_columnar_is_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "run.parquet"
    path.write_text("t,lat,lon,alt\n1,60,24,0\n")
    with pytest.raises(RunFormatError, match=r"run\.parquet \(line n/a\): field \(whole file\): not a readable Parquet file"):
        read_run(path)


def test_threaded_csv_slices_write_the_bytes_of_one_writer(tmp_path: Path, monkeypatch) -> None:
    import posefix.io.csv as iocsv

    run = small_run(n=1000)
    write_run(run, tmp_path / "one.csv")
    monkeypatch.setattr(iocsv, "WRITE_SLICE_ROWS", 150)
    monkeypatch.setattr(iocsv.os, "cpu_count", lambda: 4)
    assert len(iocsv._csv_chunks(iocsv.run_to_table(run))) == 4
    write_run(run, tmp_path / "four.csv")
    assert (tmp_path / "one.csv").read_bytes() == (tmp_path / "four.csv").read_bytes()
