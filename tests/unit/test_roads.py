"""Road-network matching on the shipped Helsinki extract: a simulated drive along its
streets, the reported positions offset as a GNSS bias would, matched back onto the roads."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.core.simulate import simulate
from posefix.mapmatch.osm import local_georef
from posefix.mapmatch.suggest import heading_from_quaternion_wxyz
from posefix.roads import match_on_roads

from .io_helpers import osm_extract


@pytest.fixture(scope="module")
def drive():
    sim = simulate(duration_s=180.0, rate_hz=1.0, osm_path=str(osm_extract()), seed=5, edit_every_s=0, regime="white")
    return sim.truth


def _error_m(lonlat: np.ndarray, truth) -> np.ndarray:
    geo = local_georef(float(truth.lon_deg[0]), float(truth.lat_deg[0]))
    return np.linalg.norm(geo.to_xy(lonlat) - geo.to_xy(np.column_stack([truth.lon_deg, truth.lat_deg])), axis=1)


def _offset(truth, east_m: float, north_m: float) -> tuple[np.ndarray, np.ndarray]:
    geo = local_georef(float(truth.lon_deg[0]), float(truth.lat_deg[0]))
    p = geo.to_xy(np.column_stack([truth.lon_deg, truth.lat_deg])) + [east_m, north_m]
    ll = geo.to_lonlat(p)
    return ll[:, 0], ll[:, 1]


def test_a_biased_drive_is_matched_back_onto_its_streets(drive) -> None:
    lon, lat = _offset(drive, 4.0, -3.0)
    sug = match_on_roads(lon, lat, drive.q_body_to_enu_wxyz, osm_extract())
    before = _error_m(np.column_stack([lon, lat]), drive)
    after = _error_m(sug.lonlat_deg, drive)
    assert np.median(after) < 0.3 * np.median(before), (np.median(before), np.median(after))
    assert np.allclose(sug.moved_m, _error_m(sug.lonlat_deg, _shifted(drive, lon, lat)), atol=0.02)
    assert np.all(np.isfinite(sug.sigma_m)) and np.all(sug.sigma_m > 0)
    assert sug.n_vertices > 1000  # road segments of the box


def _shifted(drive, lon, lat):
    import dataclasses

    return dataclasses.replace(drive, lon_deg=lon, lat_deg=lat)


def _far_from_roads(drive, min_m: float = 25.0) -> tuple[float, float]:
    """A point near the drive at least ``min_m`` from every drivable way (shapely, not our index)."""
    from shapely.geometry import LineString, Point

    from posefix.mapmatch.osm import read_osm_ways

    geo = local_georef(float(drive.lon_deg.min()) - 0.003, float(drive.lat_deg.min()) - 0.002)
    box = (geo.lon0_deg, geo.lat0_deg, float(drive.lon_deg.max()) + 0.003, float(drive.lat_deg.max()) + 0.002)
    lines = [LineString(geo.to_xy(w.lonlat_deg)) for w in read_osm_ways(osm_extract(), box, profile="drive")]
    hi = geo.to_xy(np.array([[box[2], box[3]]]))[0]
    for x in np.arange(0.0, hi[0], 10.0):
        for y in np.arange(0.0, hi[1], 10.0):
            if min(line.distance(Point(x, y)) for line in lines) > min_m:
                lon, lat = geo.to_lonlat(np.array([[x, y]]))[0]
                return float(lon), float(lat)
    raise AssertionError("no point far from the roads in the box")


def test_off_road_flags_the_reported_position_outside_every_carriageway(drive) -> None:
    on_centreline = match_on_roads(drive.lon_deg, drive.lat_deg, drive.q_body_to_enu_wxyz, osm_extract()).off_road
    assert on_centreline.mean() < 0.05  # the simulated truth drives along the ways' centrelines
    lon, lat = drive.lon_deg.copy(), drive.lat_deg.copy()
    i = len(lon) // 2
    lon[i], lat[i] = _far_from_roads(drive)
    flagged = match_on_roads(lon, lat, drive.q_body_to_enu_wxyz, osm_extract()).off_road
    assert flagged[i]
    assert np.array_equal(np.delete(flagged, i), np.delete(on_centreline, i))


def test_bad_inputs_name_the_file(tmp_path, drive) -> None:
    q = drive.q_body_to_enu_wxyz
    with pytest.raises(ValueError, match="missing.osm.pbf"):
        match_on_roads(drive.lon_deg, drive.lat_deg, q, tmp_path / "missing.osm.pbf")
    with pytest.raises(ValueError, match=r"helsinki\.osm\.pbf.*no drive ways"):
        match_on_roads(drive.lon_deg + 1.0, drive.lat_deg, q, osm_extract())
    with pytest.raises(ValueError, match="two keyframes"):
        match_on_roads(drive.lon_deg[:1], drive.lat_deg[:1], q[:1], osm_extract())


def test_the_bias_along_a_road_is_corrected_where_the_run_turns(drive) -> None:
    # 12 m along the first street and 5 m across: a projection alone keeps the 12 m
    geo = local_georef(float(drive.lon_deg[0]), float(drive.lat_deg[0]))
    truth = geo.to_xy(np.column_stack([drive.lon_deg, drive.lat_deg]))
    along = truth[5] - truth[0]
    along /= np.linalg.norm(along)
    shift = 12.0 * along + 5.0 * np.array([-along[1], along[0]])
    ll = geo.to_lonlat(truth + shift)
    sug = match_on_roads(ll[:, 0], ll[:, 1], drive.q_body_to_enu_wxyz, osm_extract(), t_s=drive.t_s)
    after = _error_m(sug.lonlat_deg, drive)
    assert np.median(after) < 2.0, np.median(after)
    assert sug.matcher == "roads"


def test_the_two_solvers_of_the_bias_agree() -> None:
    from posefix.roads import match as m
    from posefix.roads.network import road_network

    sim = simulate(duration_s=120.0, rate_hz=1.0, osm_path=str(osm_extract()), seed=9, edit_every_s=0, regime="canyon")
    ll = np.column_stack([sim.run.lon_deg, sim.run.lat_deg])
    net = road_network(osm_extract(), (ll[:, 0].min() - 0.002, ll[:, 1].min() - 0.001, ll[:, 0].max() + 0.002,
                                        ll[:, 1].max() + 0.001))
    p = net.georef.to_xy(ll)
    heading = heading_from_quaternion_wxyz(sim.run.q_body_to_enu_wxyz)
    near = m.candidates(net, p)
    state, matched, on_road, _, _ = m._viterbi_pass(near, p, heading, False)
    seg = np.where(on_road, near[3][np.arange(len(p)), np.minimum(state, m.K - 1)], -1)
    dt = np.full(len(p) - 1, 1.0)
    args = (net, p, np.zeros_like(p), 0.0, matched, seg, heading, dt, 6.0, m.TAU_S, m.RATE_M_PER_SQRT_S, True)
    banded, _, offset = m._smooth_bias(*args, covariance=False)
    rts, cov, offset_rts = m._smooth_bias(*args, covariance=True)
    assert np.abs(banded - rts).max() < 1e-6 and offset == offset_rts
    assert np.all(cov[:, 0] > 0) and np.all(cov[:, 0] * cov[:, 2] > cov[:, 1] ** 2)


def test_a_run_away_from_the_roads_falls_back_to_the_grid(drive) -> None:
    from posefix.roads import FewRoadsNear, suggest_vehicle_run

    lon0, lat0 = _far_from_roads(drive, min_m=60.0)
    geo = local_georef(lon0, lat0)
    a = np.linspace(0.0, 2 * np.pi, 30)
    ll = geo.to_lonlat(np.column_stack([8.0 * np.cos(a), 8.0 * np.sin(a)]))
    q = np.tile([1.0, 0.0, 0.0, 0.0], (a.size, 1))
    with pytest.raises(FewRoadsNear):
        match_on_roads(ll[:, 0], ll[:, 1], q, osm_extract(), min_near_share=0.5)
    sug = suggest_vehicle_run(ll[:, 0], ll[:, 1], q, osm_extract())
    assert sug.matcher == "grid" and sug.off_road.all()
    assert suggest_vehicle_run(drive.lon_deg, drive.lat_deg, drive.q_body_to_enu_wxyz, osm_extract()).matcher == "roads"
    with pytest.raises(ValueError, match="field matcher"):
        suggest_vehicle_run(ll[:, 0], ll[:, 1], q, osm_extract(), matcher="nearest")


def test_keyframe_times_must_increase(drive) -> None:
    t = drive.t_s.copy()
    t[7] = t[6]
    with pytest.raises(ValueError, match="keyframe 7: field t_s"):
        match_on_roads(drive.lon_deg, drive.lat_deg, drive.q_body_to_enu_wxyz, osm_extract(), t_s=t)
    lat = drive.lat_deg.copy()
    lat[4] = np.nan
    with pytest.raises(ValueError, match="keyframe 4: field lat: not a finite number"):
        match_on_roads(drive.lon_deg, lat, drive.q_body_to_enu_wxyz, osm_extract())


def test_cli_suggest_writes_one_line_per_keyframe(tmp_path) -> None:
    from click.testing import CliRunner

    from posefix.cli import build_app
    from posefix.io import write_run

    sim = simulate(duration_s=60.0, rate_hz=10.0, osm_path=str(osm_extract()), seed=3, edit_every_s=0, regime="canyon")
    write_run(sim.run, tmp_path / "run.csv")
    out = CliRunner().invoke(build_app(), ["mapmatch", "suggest", str(tmp_path / "run.csv"), "--osm", str(osm_extract()),
                                           "-o", str(tmp_path / "s.csv")])
    assert out.exit_code == 0, out.output
    assert "61 keyframes on the roads matcher" in out.output
    rows = np.genfromtxt(tmp_path / "s.csv", delimiter=",", names=True)
    assert rows.size == 61 and np.array_equal(rows["row"], np.arange(0, 601, 10))
    before = _error_m(np.column_stack([sim.run.lon_deg[::10], sim.run.lat_deg[::10]]), _rows(sim.truth, slice(None, None, 10)))
    after = _error_m(np.column_stack([rows["lon"], rows["lat"]]), _rows(sim.truth, slice(None, None, 10)))
    assert np.mean(after) < np.mean(before), (np.mean(before), np.mean(after))
    bad = CliRunner().invoke(build_app(), ["mapmatch", "suggest", str(tmp_path / "run.csv"), "--osm",
                                           str(tmp_path / "none.pbf"), "-o", str(tmp_path / "t.csv")])
    assert bad.exit_code == 1 and "none.pbf" in bad.output and not (tmp_path / "t.csv").exists()


def _rows(run, sl):
    import dataclasses

    return dataclasses.replace(run, lon_deg=run.lon_deg[sl], lat_deg=run.lat_deg[sl])


def test_a_drive_in_the_right_lane_keeps_its_lane() -> None:
    from posefix.roads.match import match_xy
    from posefix.roads.network import road_network

    sim = simulate(duration_s=300.0, rate_hz=1.0, osm_path=str(osm_extract()), seed=4, edit_every_s=0, regime="white")
    ll = np.column_stack([sim.truth.lon_deg, sim.truth.lat_deg])
    net = road_network(osm_extract(), (ll[:, 0].min() - 0.002, ll[:, 1].min() - 0.001, ll[:, 0].max() + 0.002,
                                        ll[:, 1].max() + 0.001))
    heading = heading_from_quaternion_wxyz(sim.truth.q_body_to_enu_wxyz)
    lane = net.georef.to_xy(ll) + 1.75 * np.column_stack([np.sin(heading), -np.cos(heading)])  # right of travel
    reported = lane + [6.0, -4.0]
    matched, _, _, _, offset = match_xy(net, reported, heading)
    centreline, _, _, _, none = match_xy(net, reported, heading, sigma_lane=1e-6)
    assert 1.0 < offset < 2.5 and abs(none) < 1e-3, (offset, none)
    err, err_centre = np.linalg.norm(matched - lane, axis=1), np.linalg.norm(centreline - lane, axis=1)
    assert np.median(err) < 0.6 * np.median(err_centre), (np.median(err), np.median(err_centre))
