"""Edit rules against the shared vectors (the browser's vitest reads the same file)."""

import json
from pathlib import Path

import numpy as np
import pytest

from posefix.core.rules import REASONS, EditRules, KeyframeMove, adjustable_mask, check_edits, locked_mask, ordinal

VECTORS = Path(__file__).resolve().parents[1] / "vectors" / "edit_rules.json"
CASES = json.loads(VECTORS.read_text())["cases"]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_shared_vector(case):
    rules = EditRules.from_json(case["rules"])
    en = np.array(case["keyframes_en_m"], dtype=float)
    k = len(en)
    before = {e["index"]: (e["east_m"], e["north_m"]) for e in case["edited_before"]}
    moves = [KeyframeMove(m["index"], m["east_m"], m["north_m"]) for m in case["moves"]]
    exp = case["expected"]
    assert adjustable_mask(k, rules).tolist() == exp["adjustable"]
    assert locked_mask(k, sorted(before), rules).tolist() == exp["locked"]
    out = check_edits(rules, en, moves, case["deleted"], before)
    assert sorted(m.index for m in out.accepted) == exp["accepted"]
    assert [{"index": r.index, "reason": r.reason} for r in out.refusals] == exp["refusals"]
    assert [{"index": r.index, "reason": r.reason} for r in out.flags] == exp["flags"]
    for r in out.refusals + out.flags:
        assert r.reason in REASONS and len(r.message) > 10


def test_vectors_cover_every_reason():
    seen = {r["reason"] for c in CASES for r in c["expected"]["refusals"] + c["expected"]["flags"]}
    assert seen == set(REASONS)


def test_rules_round_trip_json():
    rules = EditRules(every_n=4, lock_n=2, lock_direction="both", max_move_m=30.0, order_rule="refuse", deleted="flag")
    assert EditRules.from_json(json.loads(json.dumps(rules.to_json()))) == rules


def test_messages_name_the_keyframe_and_limit():
    rules = EditRules(max_move_m=5.0)
    out = check_edits(rules, np.zeros((3, 2)), [KeyframeMove(1, 30.0, 40.0)])
    assert out.refusals[0].reason == "too_far"
    assert "keyframe 1" in out.refusals[0].message.lower() and "50.0 m" in out.refusals[0].message and "5 m" in out.refusals[0].message


def test_messages_read_as_english_for_any_count():
    en = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    out = check_edits(EditRules(every_n=2, lock_n=1), en, [KeyframeMove(0, 0.0, 1.0), KeyframeMove(1, 10.0, 1.0)])
    assert "every 2nd keyframe" in out.refusals[0].message
    out = check_edits(EditRules(lock_n=1), en, [KeyframeMove(2, 20.0, 1.0)], edited_before={1: (10.0, 1.0)})
    assert "within 1 keyframe of" in out.refusals[0].message
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111)] == \
        ["1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st", "111th"]
