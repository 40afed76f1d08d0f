"""Interchange CSV: round trips, derived orientation, and every bad-input case."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from posefix.io import OrientationDerivedWarning, RunFormatError, read_run, write_run
from posefix.io.atomic import atomic_write
from posefix.io import csv as csv_module
from posefix.io.csv import read_csv

from .io_helpers import leftovers, small_run


@pytest.fixture(autouse=True, params=["stdlib", "arrow"])
def reader(request, monkeypatch):
    """Every case on both readers: small files by the standard library, the rest by Arrow."""
    if request.param == "arrow":
        monkeypatch.setattr(csv_module, "SMALL_FILE_BYTES", 0)
    return request.param

HEADER = "t,lat,lon,alt,qw,qx,qy,qz"
GOOD = [
    "0.0,60.17,24.94,20.0,1,0,0,0",
    "0.1,60.17001,24.94,20.0,1,0,0,0",
    "0.2,60.17002,24.94,20.0,1,0,0,0",
    "0.3,60.17003,24.94,20.0,1,0,0,0",
]


def _write(tmp_path: Path, lines: list[str], name: str = "run.csv") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_round_trip_keeps_every_column(tmp_path):
    run = small_run()
    out = tmp_path / "out.csv"
    write_run(run, out)
    back = read_run(out)
    assert back.n == run.n
    assert np.array_equal(back.t_s, run.t_s)  # times exactly: edits name samples by them
    assert np.abs(back.lat_deg - run.lat_deg).max() < 1e-10
    assert np.abs(back.lon_deg - run.lon_deg).max() < 1e-10
    assert np.abs(back.alt_m - run.alt_m).max() < 1e-6
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-11
    assert np.array_equal(np.isnan(back.gnss_lat_deg), np.isnan(run.gnss_lat_deg))
    ok = ~np.isnan(run.gnss_lat_deg)
    assert np.abs(back.gnss_lon_deg[ok] - run.gnss_lon_deg[ok]).max() < 1e-10
    assert back.images == run.images
    assert list(back.extra) == ["speed_mps", "note"]
    assert back.extra["note"].tolist() == run.extra["note"].tolist()  # commas survive quoting
    assert np.allclose(back.extra["speed_mps"].astype(float), 10.0)
    assert not back.orientation_derived


def test_exact_mode_round_trips_bit_for_bit(tmp_path):
    from posefix.io.csv import write_csv

    run = small_run(gnss=False, images=False, extra=False)
    write_csv(run, tmp_path / "x.csv", exact=True)
    back = read_csv(tmp_path / "x.csv")
    for name in ("t_s", "lat_deg", "lon_deg", "alt_m"):
        assert np.array_equal(getattr(back, name), getattr(run, name))


def test_columns_in_any_order_and_blank_lines(tmp_path):
    lines = ["lon,t,qz,alt,lat,qw,qx,qy", "24.94,0,0,20,60.17,1,0,0", "", "24.94,1,0,20,60.18,1,0,0"]
    run = read_run(_write(tmp_path, lines))
    assert run.n == 2 and run.lat_deg[1] == 60.18 and run.t_s[1] == 1.0


def test_missing_orientation_is_derived_with_a_warning(tmp_path):
    # eastward then northward
    lines = ["t,lat,lon,alt"] + [f"{i},60.0,{24.0 + i * 1e-4},0" for i in range(5)] + \
            [f"{i + 5},{60.0 + (i + 1) * 1e-4},{24.0 + 4e-4},0" for i in range(5)]
    with pytest.warns(OrientationDerivedWarning, match="heading derived"):
        run = read_run(_write(tmp_path, lines))
    assert run.orientation_derived
    yaw = 2 * np.arctan2(run.q_body_to_enu_wxyz[:, 3], run.q_body_to_enu_wxyz[:, 0])
    assert abs(np.degrees(yaw[1])) < 1.0  # east
    assert abs(np.degrees(yaw[-2]) - 90.0) < 1.0  # north
    assert np.allclose(run.q_body_to_enu_wxyz[:, 1:3], 0.0)  # no roll, no pitch


def test_stationary_samples_take_the_nearest_moving_heading(tmp_path):
    lines = ["t,lat,lon,alt"] + [f"{i},60.0,24.0,0" for i in range(3)] + [f"{i + 3},{60.0 + (i + 1) * 1e-4},24.0,0" for i in range(4)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OrientationDerivedWarning)
        run = read_run(_write(tmp_path, lines))
    yaw = np.degrees(2 * np.arctan2(run.q_body_to_enu_wxyz[:, 3], run.q_body_to_enu_wxyz[:, 0]))
    assert np.allclose(yaw, 90.0, atol=1.0)


BAD_CASES = [
    # (lines, line, field, message fragment)
    ([HEADER, GOOD[0], "0.1,60.17,abc,20,1,0,0,0"], 3, "lon", "not a number"),
    ([HEADER, GOOD[0], "0.1,60.17,24.94,nan,1,0,0,0"], 3, "alt", "NaN"),
    ([HEADER, GOOD[0], GOOD[1], "0.2,,24.94,20,1,0,0,0"], 4, "lat", "missing"),
    ([HEADER, GOOD[0], "0.1,91.5,24.94,20,1,0,0,0"], 3, "lat", "outside [-90, 90]"),
    ([HEADER, GOOD[0], GOOD[1], "0.2,60.0,-180.5,20,1,0,0,0"], 4, "lon", "outside [-180, 180]"),
    ([HEADER, GOOD[0], GOOD[1], "0.1,60.17,24.94,20,1,0,0,0"], 4, "t", "not strictly increasing"),
    ([HEADER, GOOD[0], GOOD[1], "0.05,60.17,24.94,20,1,0,0,0"], 4, "t", "0.05 follows 0.1"),
    ([HEADER, GOOD[0], "0.1,60.17,24.94,20,0,0,0,0"], 3, "qw,qx,qy,qz", "zero quaternion"),
    ([HEADER, GOOD[0], "0.1,60.17,24.94,20,2,0,0,0"], 3, "qw,qx,qy,qz", "norm"),
    (["t,lat,alt,qw,qx,qy,qz", "0,60,20,1,0,0,0"], 1, "lon", "missing required column"),
    (["t,lat,lon,alt,qw,qx,qy", "0,60,24,20,1,0,0"], 1, "qz", "all of qw,qx,qy,qz"),
    (["t,lat,lon,alt,gnss_lat", "0,60,24,20,60"], 1, "gnss_lon,gnss_alt", "gnss_lat,gnss_lon,gnss_alt"),
    ([HEADER], 2, None, "empty"),
    ([HEADER, GOOD[0], "0.1,60.17,24.94"], 3, None, "expected 8 fields, found 3"),
    ([HEADER, GOOD[0], "", GOOD[1], "", "0.2,60.0,24.94,x,1,0,0,0"], 6, "alt", "not a number"),
    # two bad fields: the first line in the file is named, whichever column comes first
    ([HEADER, GOOD[0], "0.1,60.17,24.94,x,1,0,0,0", "0.2,60.17,abc,20,1,0,0,0"], 3, "alt", "not a number"),
    ([HEADER, GOOD[0], "", GOOD[1], "", "0.05,60.0,24.94,1,1,0,0,0"], 6, "t", "not strictly increasing"),
    (["t,lat,lat,lon,alt", "0,1,1,1,1"], 1, "lat", "twice"),
]


@pytest.mark.parametrize("lines,line,field,fragment", BAD_CASES)
def test_bad_input_names_file_line_and_field(tmp_path, lines, line, field, fragment):
    path = _write(tmp_path, lines)
    with pytest.raises(RunFormatError) as info:
        read_run(path)
    err = info.value
    assert err.file == str(path)
    assert err.line == line
    assert err.field == field
    assert fragment in err.message
    text = str(err)
    assert f"{path}:{line}" in text and (field or "(whole file)") in text


def test_empty_file_and_missing_file(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(RunFormatError, match="empty file"):
        read_run(empty)
    with pytest.raises(RunFormatError, match="no such file"):
        read_run(tmp_path / "absent.csv")


def test_gnss_gaps_are_allowed_but_not_in_pose_columns(tmp_path):
    lines = ["t,lat,lon,alt,gnss_lat,gnss_lon,gnss_alt", "0,60,24,0,,,", "1,60.0001,24,0,60.0001,24,NaN"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OrientationDerivedWarning)
        run = read_run(_write(tmp_path, lines))
    assert np.isnan(run.gnss_lat_deg[0]) and run.gnss_lat_deg[1] == 60.0001 and np.isnan(run.gnss_alt_m[1])


def test_failed_write_leaves_target_and_no_temp_file(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old content\n")
    with pytest.raises(RuntimeError):
        with atomic_write(target, "w") as fh:
            fh.write("partial")
            raise RuntimeError("disk on fire")
    assert target.read_text() == "old content\n"
    assert leftovers(tmp_path) == []


def test_write_into_missing_folder_is_refused(tmp_path):
    with pytest.raises(RunFormatError, match="does not exist"):
        write_run(small_run(), tmp_path / "nope" / "out.csv")


def test_unknown_extension_is_refused(tmp_path):
    p = tmp_path / "run.xyz"
    p.write_text("x")
    with pytest.raises(RunFormatError, match="unknown file extension"):
        read_run(p)


def test_bom_crlf_and_spaced_header_names(tmp_path):
    p = tmp_path / "win.csv"
    p.write_bytes(b"\xef\xbb\xbft, lat ,lon,alt,qw,qx,qy,qz\r\n0,60,24,0,1,0,0,0\r\n\r\n1,60.0001,24,0,1,0,0,0\r\n")
    run = read_run(p)
    assert run.n == 2 and run.lat_deg[1] == 60.0001
    p.write_bytes(p.read_bytes() + b"2,60.0002,24,0,x,0,0,0\r\n")
    with pytest.raises(RunFormatError) as info:
        read_run(p)
    assert (info.value.line, info.value.field) == (5, "qw")


def test_both_readers_give_the_same_run(tmp_path):
    run = small_run()
    out = tmp_path / "out.csv"
    write_run(run, out)
    a = read_csv(out)
    size = csv_module.SMALL_FILE_BYTES
    try:
        csv_module.SMALL_FILE_BYTES = 0
        b = read_csv(out)
    finally:
        csv_module.SMALL_FILE_BYTES = size
    for name in ("t_s", "lat_deg", "lon_deg", "alt_m", "q_body_to_enu_wxyz", "gnss_lat_deg", "gnss_lon_deg", "gnss_alt_m"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or np.array_equal(x, y, equal_nan=True), name
    assert a.images == b.images
    assert a.extra.keys() == b.extra.keys()
    for k in a.extra:
        assert a.extra[k].dtype == b.extra[k].dtype and np.array_equal(a.extra[k], b.extra[k])


@pytest.mark.parametrize("value", ["1_0", "0x10", "abc"])
def test_numbers_arrow_refuses_are_refused_by_both(tmp_path, value):
    p = _write(tmp_path, [HEADER, GOOD[0], f"{value},60.17001,24.94,20.0,1,0,0,0"])
    with pytest.raises(RunFormatError) as err:
        read_csv(p)
    assert ":3: field t: not a number" in str(err.value)


@pytest.mark.parametrize("exact", [False, True])
@pytest.mark.parametrize("extra", [False, True])
def test_small_writer_makes_arrow_writers_bytes(exact, extra):
    from posefix.io.csv import _csv_chunks, _csv_small, run_to_table

    run = small_run(n=300, extra=extra)
    # every notation Arrow uses: fixed, exponent, integral, tiny, huge, inf, NaN (a gap)
    odd = np.array([0.0, 1e-7, 1.25e-6, 9.99e-5, 1e10, 1.5e15, -2.5e-9, np.inf, -np.inf, np.nan, 123.0, -0.0])
    run.alt_m[:len(odd)] = odd
    run.gnss_alt_m[len(odd):2 * len(odd)] = odd
    want = b"".join(bytes(c) for c in _csv_chunks(run_to_table(run, exact=exact)))
    got = _csv_small(run, exact)
    if extra:  # a numeric extra column: Arrow's own formatting of ints and bools is not copied
        assert got is None
    else:
        assert got == want
        rng = np.random.default_rng(1)
        vals = rng.standard_normal(5000) * 10.0 ** rng.integers(-12, 22, 5000)
        run.alt_m[:] = vals[:run.n]
        assert _csv_small(run, True) == b"".join(bytes(c) for c in _csv_chunks(run_to_table(run, exact=True)))
