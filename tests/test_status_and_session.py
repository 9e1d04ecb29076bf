import math

import pytest

from drivers.board_protocol import Hello, Sample, Status
from drivers.published_values import StatusBits
from gateway.board_session import BoardSession
from gateway.core.conversion import AxisCalibration, Calibration
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.status_flags import EVENT_HOLD_S, GatewayCondition, status_bits


def cond(**kw):
    base = dict(now_s=100.0, have_estimate=True, port_open=True, last_sample_s=99.999, last_byte_s=99.999,
                stale_after_s=0.1, lost_after_s=2.0, referenced=True)
    base.update(kw)
    return GatewayCondition(**base)


def test_fresh_referenced_estimate_is_valid_and_nothing_else():
    assert status_bits(cond()) == StatusBits.VALID


def test_stale_then_board_lost_clear_valid():
    assert status_bits(cond(last_sample_s=99.5)) == StatusBits.STALE
    bits = status_bits(cond(last_sample_s=97.0, last_byte_s=97.0))
    assert bits == StatusBits.STALE | StatusBits.BOARD_LOST
    bits = status_bits(cond(port_open=False))
    assert StatusBits.BOARD_LOST in bits and StatusBits.VALID not in bits


def test_start_up_before_any_sample_is_lost_stale_and_not_referenced():
    bits = status_bits(cond(have_estimate=False, last_sample_s=None, last_byte_s=None, referenced=False))
    assert bits == StatusBits.STALE | StatusBits.BOARD_LOST | StatusBits.NOT_REFERENCED


def test_not_referenced_does_not_clear_valid_but_faults_do():
    assert status_bits(cond(referenced=False)) == StatusBits.VALID | StatusBits.NOT_REFERENCED
    for kw, bit in (("estimator_fault", StatusBits.ESTIMATOR_FAULT), ("holding", StatusBits.HOLDING),
                    ("axis_invalid", StatusBits.AXIS_INVALID)):
        assert status_bits(cond(**{kw: True})) == bit


def test_events_stay_visible_for_the_hold_time():
    bits = status_bits(cond(board_reset_at_s=95.0, samples_lost_at_s=99.0, config_reloaded_at_s=91.0,
                            saturated_until_s=100.5))
    assert bits == (StatusBits.VALID | StatusBits.BOARD_RESET | StatusBits.SAMPLES_LOST
                    | StatusBits.CONFIG_RELOADED | StatusBits.SATURATED)
    later = 100.0 + EVENT_HOLD_S
    assert status_bits(cond(now_s=later, last_sample_s=later, last_byte_s=later, board_reset_at_s=95.0,
                            saturated_until_s=100.5)) == StatusBits.VALID


REPORT = dict(uptime_s=0, tick_hz=921_600, temp_centi_c=2512, fw_major=1, fw_minor=0)


def test_session_waits_for_the_tick_rate_then_times_and_converts():
    s = BoardSession(Calibration())
    assert s.on_sample(Sample(0, 921, 925, 1843)) is None
    assert s.counters.samples_without_tick_rate == 1
    assert s.on_report(Status(seq=0, **REPORT)) is False
    a = s.on_sample(Sample(1, 921, 925, 1843))
    b = s.on_sample(Sample(4, 921, 925, 1843, lost_before=2))
    assert a.t_s == 0.0
    assert b.t_s == pytest.approx(3 * 1843 / 921_600)
    assert a.acc_mps2 == pytest.approx((921 / 1843 - 0.5) / 0.125 * STANDARD_GRAVITY_MPS2)
    assert s.temp_c == pytest.approx(25.12)


def test_session_axis_and_calibration_and_flags():
    s = BoardSession(Calibration(y=AxisCalibration(0.51, 0.12)), axis="y")
    s.on_report(Hello(seq=0xFFFF, **REPORT))
    got = s.on_sample(Sample(0, 100, 1843 * 0.63, 1843))
    assert got.acc_mps2 == pytest.approx((0.63 - 0.51) / 0.12 * STANDARD_GRAVITY_MPS2, rel=1e-3)
    flagged = s.on_sample(Sample(1, 921, 925, 1843, flags=0x02))
    assert flagged.acc_mps2 is None and flagged.saturated
    clipped = s.on_sample(Sample(2, 921, int(1843 * 0.76), 1843))
    assert clipped.saturated


def test_first_hello_is_power_on_later_ones_and_uptime_going_back_are_resets():
    s = BoardSession(Calibration())
    assert s.on_report(Hello(seq=0xFFFF, **REPORT)) is False
    s.on_report(Status(seq=10, **{**REPORT, "uptime_s": 50}))
    s.on_sample(Sample(11, 921, 925, 1843))
    assert s.on_report(Hello(seq=0xFFFF, **REPORT)) is True
    s.on_report(Status(seq=10, **{**REPORT, "uptime_s": 60}))
    assert s.on_report(Status(seq=10, **{**REPORT, "uptime_s": 3})) is True  # HELLO lost on the line
    assert (s.counters.resets_announced, s.counters.resets_inferred) == (1, 1)
    assert s.on_sample(Sample(0, 921, 925, 1843)).t_s == 0.0
