"""GPX 1.1: round trips, plain tracks from other tools, and refused input."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.io import OrientationDerivedWarning, RunFormatError, read_run, write_run

from .io_helpers import small_run

PLAIN = """<?xml version="1.0" encoding="UTF-8"?>
<gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1">
  <trk><name>walk</name>
    <trkseg>
      <trkpt lat="60.1700" lon="24.9400"><ele>10.5</ele><time>2024-05-01T10:00:00Z</time></trkpt>
      <trkpt lat="60.1700" lon="24.9402"><ele>10.6</ele><time>2024-05-01T10:00:01.250Z</time></trkpt>
      <trkpt lat="60.1700" lon="24.9404"><time>2024-05-01T10:00:02Z</time></trkpt>
    </trkseg>
  </trk>
</gpx>
"""


def test_round_trip_keeps_pose_and_gnss(tmp_path):
    run = small_run(images=False, extra=False)
    write_run(run, tmp_path / "r.gpx")
    back = read_run(tmp_path / "r.gpx")
    assert back.n == run.n and not back.orientation_derived
    assert np.abs(back.t_s - run.t_s).max() < 1e-6  # microseconds in GPX times
    assert np.array_equal(back.lat_deg, run.lat_deg) and np.array_equal(back.lon_deg, run.lon_deg)
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-15
    assert np.array_equal(np.isnan(back.gnss_lat_deg), np.isnan(run.gnss_lat_deg))


def test_plain_track_gets_times_elevation_and_derived_heading(tmp_path):
    p = tmp_path / "plain.gpx"
    p.write_text(PLAIN)
    with pytest.warns(OrientationDerivedWarning):
        run = read_run(p)
    assert run.n == 3 and run.orientation_derived and not run.has_gnss
    assert run.t_s[1] - run.t_s[0] == pytest.approx(1.25)
    assert run.t_s[0] == pytest.approx(1714557600.0)
    assert run.alt_m.tolist() == [10.5, 10.6, 0.0]
    yaw = np.degrees(2 * np.arctan2(run.q_body_to_enu_wxyz[:, 3], run.q_body_to_enu_wxyz[:, 0]))
    assert np.allclose(yaw, 0.0, atol=0.5)  # heading east


BOMB = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">]>
<gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1"><trk><name>&lol3;</name></trk></gpx>
"""
EXTERNAL = """<?xml version="1.0"?>
<!DOCTYPE gpx [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>
<gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1"><trk><name>&xxe;</name></trk></gpx>
"""


@pytest.mark.parametrize("text", [BOMB, EXTERNAL])
def test_entity_expansion_and_external_entities_are_refused(tmp_path, text):
    p = tmp_path / "evil.gpx"
    p.write_text(text)
    with pytest.raises(RunFormatError, match="DTD or entities") as info:
        read_run(p)
    assert info.value.field == "DOCTYPE"


def _with_points(points: str) -> str:
    return ('<?xml version="1.0"?>\n<gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1">\n'
            f"<trk><trkseg>\n{points}</trkseg></trk>\n</gpx>\n")


OK1 = '<trkpt lat="60.17" lon="24.94"><time>2024-05-01T10:00:00Z</time></trkpt>\n'
OK2 = '<trkpt lat="60.1701" lon="24.94"><time>2024-05-01T10:00:01Z</time></trkpt>\n'


@pytest.mark.parametrize("points,line,field,fragment", [
    (OK1 + '<trkpt lat="60.17" lon="24.94"></trkpt>\n', 5, "time", "no (valid) <time>"),
    (OK1 + OK2 + '<trkpt lat="95" lon="24.94"><time>2024-05-01T10:00:02Z</time></trkpt>\n', 6, "lat", "outside [-90, 90]"),
    (OK1 + OK2 + '<trkpt lat="60.17" lon="24.94"><time>2024-05-01T10:00:00Z</time></trkpt>\n', 6, "time", "not strictly increasing"),
    (OK1 + "<trkpt lat=", 5, None, "not well-formed"),
    (OK1 + '<trkpt lat="abc" lon="24.94"><time>2024-05-01T10:00:01Z</time></trkpt>\n', 5, "lat", "not a number"),
    (OK1 + OK2 + '<trkpt lat="60.17" lon="24.94">\n<ele>high</ele><time>2024-05-01T10:00:02Z</time></trkpt>\n', 7, "ele", "not a number"),
    (OK1 + '<trkpt lat="60.17" lon="24.94"><time>yesterday</time></trkpt>\n', 5, "time", "no (valid) <time>"),
    ("", None, "trkpt", "empty"),
])
def test_bad_gpx_names_line_and_field(tmp_path, points, line, field, fragment):
    p = tmp_path / "bad.gpx"
    p.write_text(_with_points(points))
    with pytest.raises(RunFormatError) as info:
        read_run(p)
    assert (info.value.line, info.value.field) == (line, field)
    assert fragment in info.value.message


def _gpx_rows_as_before(run) -> bytes:
    """The track points as the writer rendered them before threads and integer-built times:
    every column at once through Arrow, times through numpy's datetime formatting."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from posefix.io._timeconv import s_to_iso_utc

    def col(v):
        if isinstance(v, np.ndarray):
            text = pc.cast(pa.array(v), pa.large_string())
            return pc.if_else(pa.array(np.isnan(v)), pa.scalar("", pa.large_string()), text)
        return pa.array(v, type=pa.large_string())

    q = run.q_body_to_enu_wxyz
    pieces = ['<trkpt lat="', run.lat_deg, '" lon="', run.lon_deg, '"><ele>', run.alt_m, "</ele><time>",
              s_to_iso_utc(run.t_s).tolist(), '</time><extensions><pf:pose qw="', q[:, 0], '" qx="', q[:, 1],
              '" qy="', q[:, 2], '" qz="', q[:, 3], '" gnss_lat="', run.gnss_lat_deg, '" gnss_lon="',
              run.gnss_lon_deg, '" gnss_alt="', run.gnss_alt_m, '"/></extensions></trkpt>\n']
    cols = [pa.scalar(p, pa.large_string()) if isinstance(p, str) else col(p) for p in pieces]
    return "".join(pc.binary_join_element_wise(*cols, pa.scalar("", pa.large_string())).to_pylist()).encode()


def test_writer_bytes_match_the_previous_rendering(tmp_path):
    # over 65,536 rows, so several threads render chunks; times cross midnight, a new year
    # and sub-microsecond rounding; GNSS has gaps (empty attributes)
    run = small_run(n=150_000, rate_hz=97.0, t0=1_704_067_100.0000004)
    write_run(run, tmp_path / "r.gpx")
    data = (tmp_path / "r.gpx").read_bytes()
    body = data[data.index(b"<trkpt"): data.index(b"</trkseg>")]
    assert np.isnan(run.gnss_lat_deg).any()
    assert body == _gpx_rows_as_before(run)
