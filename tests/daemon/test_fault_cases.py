"""The fault benchmark's board scripts (testing/fault_cases.py) carry the fault they
claim, decoded by the board protocol's own decoder, and their stops are true rests."""
from __future__ import annotations

import numpy as np

from drivers.board_decoder import decode_frames
from drivers.board_protocol import Hello, Sample
from testing.fault_cases import SLOT_S, Case, board_script


def _samples(script):
    return [(k, f) for k, raw in enumerate(script.frames) for f in decode_frames(raw) if isinstance(f, Sample)]


def test_a_gap_is_silent_slots_and_a_seq_gap_of_its_length():
    script = board_script(Case("gap", "gap", "acceleration", 0.020))
    silent = [k for k, raw in enumerate(script.frames) if not raw]
    assert silent == list(range(script.fault_slot, script.fault_slot + 10))
    samples = _samples(script)
    seqs = np.array([f.seq for _, f in samples])
    steps = np.diff(seqs) % 65536
    assert sorted(set(steps.tolist())) == [1, 11]  # one jump over the 10 lost samples
    # the gap is centred on the acceleration phase of the third stroke: the truth moves there
    assert script.ref_pos_m[script.fault_end_slot] != script.ref_pos_m[script.fault_slot - 1]


def test_an_outage_is_silent_for_its_length():
    script = board_script(Case("outage", "outage", length_s=2.0))
    # 2 s of the board's clock: its period (t2 counts) is within 1 % of the writer's 2 ms slot
    assert abs((script.fault_end_slot - script.fault_slot) * SLOT_S - 2.0) < 0.02
    assert not any(script.frames[script.fault_slot:script.fault_end_slot])
    assert script.frames[script.fault_end_slot]


def test_a_board_reset_is_a_hello_then_seq_from_zero_mid_move():
    script = board_script(Case("reset", "reset"))
    frames = decode_frames(script.frames[script.fault_slot])
    assert isinstance(frames[0], Hello) and isinstance(frames[1], Sample) and frames[1].seq == 0
    assert sum(isinstance(f, Hello) for raw in script.frames for f in decode_frames(raw)) == 1
    moving = script.ref_pos_m[script.fault_slot + 1] != script.ref_pos_m[script.fault_slot]
    assert moving


def test_an_offset_step_changes_the_counts_from_the_fault_on_only():
    plain = _samples(board_script(Case("none", "none")))
    stepped = board_script(Case("offset", "offset"))
    steps = _samples(stepped)
    t1_plain = np.array([f.t1x_ticks for _, f in plain])
    t1_step = np.array([f.t1x_ticks for _, f in steps[:len(plain)]])
    k = stepped.fault_slot
    assert np.array_equal(t1_plain[:k], t1_step[:k])
    # 5 mg on 0.125 duty/g over a ~1843-tick period: about +1.15 ticks on average
    assert 0.8 < np.mean(t1_step[k:k + 2000] - t1_plain[k:k + 2000]) < 1.5


def test_stops_are_true_rests_and_enough_follow_the_fault():
    for case in (Case("none", "none"), Case("outage", "outage", length_s=8.0), Case("restart", "restart")):
        script = board_script(case)
        for first, last in script.stops:
            assert np.ptp(script.ref_pos_m[first:last + 1]) == 0.0
        assert sum(first > script.fault_end_slot for first, _ in script.stops) >= 3
