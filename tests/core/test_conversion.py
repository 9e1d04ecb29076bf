import numpy as np
import pytest

from gateway.core.conversion import (
    AxisCalibration,
    acceleration_mps2,
    advance_sample_time,
    axis_valid,
    lost_before_from_seq,
    sample_times_s,
)
from gateway.core.units import STANDARD_GRAVITY_MPS2


def test_spec_example_sample_converts_by_the_data_sheet_formula():
    # board-protocol.md example: t1x=921, t1y=925, t2=1843
    cal = AxisCalibration(0.5, 0.125)
    expected_g = (921 / 1843 - 0.5) / 0.125
    assert acceleration_mps2(921, 1843, cal) == pytest.approx(expected_g * STANDARD_GRAVITY_MPS2, rel=1e-12)
    assert acceleration_mps2(925, 1843, cal) > 0 > acceleration_mps2(921, 1843, cal)


def test_per_axis_calibration_is_applied():
    cal = AxisCalibration(zero_g_duty=0.52, sensitivity_duty_per_g=0.13)
    # a duty of exactly D0 + S is 1 g
    t2 = 2000
    t1 = (0.52 + 0.13) * t2
    assert acceleration_mps2(t1, t2, cal) == pytest.approx(STANDARD_GRAVITY_MPS2)


def test_unusable_counts_are_nan_and_invalid():
    cal = AxisCalibration()
    assert np.isnan(acceleration_mps2(10, 0, cal))
    assert np.isnan(acceleration_mps2(30, 20, cal))
    flags = np.array([0, 1, 2, 4, 0, 0, 8])
    t1 = np.array([900, 900, 900, 900, 900, 1900, 900])
    t2 = np.array([1843, 1843, 1843, 1843, 0, 1843, 1843])
    assert axis_valid(flags, t1, t2, "x").tolist() == [True, False, True, False, False, False, False]
    assert axis_valid(flags, t1, t2, "y").tolist() == [True, True, False, False, False, False, False]


def test_calibration_rejects_impossible_values():
    with pytest.raises(ValueError):
        AxisCalibration(zero_g_duty=1.5)
    with pytest.raises(ValueError):
        AxisCalibration(sensitivity_duty_per_g=0.0)


def test_seq_gaps_wrap_around():
    seq = np.array([65533, 65534, 65535, 0, 1, 5, 6])
    assert lost_before_from_seq(seq).tolist() == [0, 0, 0, 0, 0, 3, 0]


def test_sample_time_is_the_sum_of_previous_periods_and_lost_ones_count():
    tick_hz = 1000.0
    t2 = np.array([2, 3, 2, 4, 2])
    lost = np.array([0, 0, 2, 0, 0])  # two samples lost before the third
    t = sample_times_s(t2, tick_hz, lost)
    # 0, 2 ms, then 3 ms of sample 1 plus two lost periods of 3 ms, ...
    assert t.tolist() == pytest.approx([0.0, 0.002, 0.005 + 0.006, 0.013, 0.017])


def test_sample_time_ignores_host_arrival_and_survives_bad_periods():
    t2 = np.array([2000, 0, 2000, 2000])
    t = sample_times_s(t2, 1e6)
    assert t.tolist() == pytest.approx([0.0, 0.002, 0.004, 0.006])


def test_a_board_reset_starts_time_over():
    # advance_sample_time is what the daemon's pipeline calls per sample; `timed` False
    # (the first sample, or the first after a reset) is t = 0 whatever came before
    t, next_t, period = advance_sample_time(False, 5.0, 0.002, 1843, 921600.0, 0)
    assert t == 0.0 and next_t == period == 1843 / 921600.0
    t, _, _ = advance_sample_time(True, next_t, period, 1843, 921600.0, 2)
    assert t == pytest.approx(3 * 1843 / 921600.0)


def test_unusable_counts_take_the_last_period_and_none_at_all_is_an_error():
    t = sample_times_s(np.array([0, 2000, 0, 2000]), 1e6)
    assert t.tolist() == pytest.approx([0.0, 0.0, 0.002, 0.004])  # no period known before the first
    with pytest.raises(ValueError):
        sample_times_s(np.zeros(5), 1e6)
