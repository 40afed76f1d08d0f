"""EDITS.json: reading, its errors, and matching edit times to samples."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posefix.io import EditMatchError, EditSet, EditsFormatError, Move, match_edits, read_edits, write_edits

from .io_helpers import small_run


def test_read_and_write_round_trip(tmp_path):
    edits = EditSet(moves=[Move(1700000000.5, 60.1, 24.9), Move(1700000001.0, 60.2, 24.8, 12.5)], deleted=[1700000002.0])
    write_edits(edits, tmp_path / "e.json")
    back = read_edits(tmp_path / "e.json")
    assert back.moves == edits.moves and back.deleted == edits.deleted
    assert back.moves[0].alt_m is None  # a 2-D edit stays 2-D


def test_missing_keys_default_to_nothing(tmp_path):
    p = tmp_path / "e.json"
    p.write_text("{}")
    assert len(read_edits(p)) == 0


@pytest.mark.parametrize("text,line,field,fragment", [
    ('{"edits": [\n {"t": 1, "lat": 60, "lon": 24},\n {"t": 2, "lat": "north", "lon": 24}\n]}', 3, "edits[1].lat", "not a number"),
    ('{"edits": [\n {"t": 1, "lat": 60}\n]}', 2, "edits[0].lon", "missing"),
    ('{"edits": [\n {"t": 1, "lat": 60, "lon": 24},\n\n {"t": 2, "lat": 99, "lon": 24}]}', 4, "edits[1].lat", "outside [-90, 90]"),
    ('{"edits": [\n {"t": 1, "lat": 60, "lon": 240}]}', 2, "edits[0].lon", "outside [-180, 180]"),
    ('{"edits": [\n {"t": NaN, "lat": 60, "lon": 24}]}', 2, "edits[0].t", "not a finite number"),
    ('{"edits": [\n {"t": 1, "lat": 60, "lon": 24, "heading": 3}]}', 2, "edits[0].heading", "unknown key"),
    ('{"edits": [], "deleted": [1, "x"]}', 1, "deleted[1]", "not a finite time"),
    ('{"edits": {}}', 1, "edits", "must be a list"),
    ('{"edits": [],\n "moves": []}', 1, "moves", "unknown key"),
    ('[1, 2]', None, "$", "top level"),
    ('{"edits": [\n {"t": 1,, }]}', 2, None, "not valid JSON"),
])
def test_bad_edits_name_line_and_field(tmp_path, text, line, field, fragment):
    p = tmp_path / "edits.json"
    p.write_text(text)
    with pytest.raises(EditsFormatError) as info:
        read_edits(p)
    assert (info.value.file, info.value.line, info.value.field) == (str(p), line, field)
    assert fragment in info.value.message


def test_match_edits_to_the_millisecond():
    run = small_run(n=20)  # 10 Hz from t0 = 1.7e9
    t = run.t_s
    edits = EditSet(moves=[Move(t[3] + 0.0004, 60.0, 24.0), Move(t[10], 60.0, 24.0)], deleted=[t[15] - 0.0004], source="e.json")
    m = match_edits(run, edits)
    assert m.move_index.tolist() == [3, 10] and m.deleted_index.tolist() == [15]


@pytest.mark.parametrize("moves,deleted,field,fragment", [
    ([0.0006], [], "edits[0].t", "matches no sample"),
    ([0.0, 0.05], [], "edits[1].t", "matches no sample"),
    ([], [-1.0], "deleted[0]", "matches no sample"),
    ([0.0, 0.1, 0.1], [], "edits[2].t", "same sample"),
    ([0.2], [0.2], "deleted[0]", "same sample"),
    ([100.0], [], "edits[0].t", "nearest sample"),
])
def test_match_edits_refuses_times_without_a_sample(moves, deleted, field, fragment):
    run = small_run(n=20)
    t0 = run.t_s[0]
    edits = EditSet(moves=[Move(t0 + dt, 60.0, 24.0) for dt in moves], deleted=[t0 + dt for dt in deleted], source="e.json")
    with pytest.raises(EditMatchError) as info:
        match_edits(run, edits)
    assert info.value.field == field and info.value.file == "e.json"
    assert fragment in info.value.message


def test_edits_written_by_the_simulator_match_exactly(tmp_path):
    run = small_run(n=30)
    edits = EditSet(moves=[Move(float(run.t_s[i]), float(run.lat_deg[i]), float(run.lon_deg[i])) for i in (5, 17)])
    write_edits(edits, tmp_path / "e.json")
    assert json.loads((tmp_path / "e.json").read_text())["edits"][0]["t"] == run.t_s[5]
    assert match_edits(run, read_edits(tmp_path / "e.json")).move_index.tolist() == [5, 17]
    assert np.isfinite(run.t_s).all()


def test_unmatched_edit_read_from_a_file_names_its_line(tmp_path):
    run = small_run(n=20)
    p = tmp_path / "edits.json"
    t = run.t_s.tolist()
    p.write_text('{"edits": [\n'
                 f' {{"t": {t[2]!r}, "lat": 60.0, "lon": 24.0}},\n'
                 f' {{"t": {t[2] + 0.01!r}, "lat": 60.0, "lon": 24.0}}\n'
                 f'],\n"deleted": [{t[2]!r}]}}')
    with pytest.raises(EditMatchError) as info:
        match_edits(run, read_edits(p))
    assert (info.value.file, info.value.line, info.value.field) == (str(p), 3, "edits[1].t")
    p.write_text('{"edits": [\n'
                 f' {{"t": {t[2]!r}, "lat": 60.0, "lon": 24.0}}\n'
                 f'],\n"deleted": [{t[2]!r}]}}')
    with pytest.raises(EditMatchError, match="same sample") as info:
        match_edits(run, read_edits(p))
    assert (info.value.line, info.value.field) == (4, "deleted[0]")
