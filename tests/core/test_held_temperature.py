"""The board's temperature as recordings carry it — the latest once-a-second STATUS value,
a staircase — made smooth again for the diagnosis (context.held_samples_smoothed)."""
import numpy as np
import pytest

from gateway.core.diagnosis.context import DiagnosisInput, held_samples_smoothed

PERIOD_S = 0.002


def _swing(t_s: np.ndarray, phase: float) -> np.ndarray:
    # a board swinging ±2 °C over 20 s (a fan cycling)
    return 25.0 + 2.0 * np.sin(2 * np.pi * t_s / 20.0 + phase)


@pytest.mark.parametrize("report_phase_s, swing_phase", [(0.0, 0.3), (0.37, 1.1), (0.9, 2.5)])
def test_a_held_staircase_is_made_smooth_again(report_phase_s, swing_phase):
    t = np.arange(0.0, 30.0, PERIOD_S)
    reported_at = np.floor(t - report_phase_s) + report_phase_s
    held = np.round(_swing(reported_at, swing_phase), 2)
    smooth = held_samples_smoothed(t, held)
    truth = _swing(t, swing_phase)
    held_err = np.abs(held - truth)
    err = np.abs(smooth - truth)
    inner = (t > 2.0) & (t < 28.0)
    # the staircase is up to a report period behind (~0.6 °C here); the spline within the
    # rounding of the reports, and at the ends far better than the staircase too
    assert held_err[inner].max() > 0.4
    assert err[inner].max() < 0.02
    assert np.sqrt(np.mean(err**2)) < 0.2 * np.sqrt(np.mean(held_err**2))


def test_a_column_that_changes_at_every_row_comes_back_unchanged():
    t = np.arange(0.0, 5.0, PERIOD_S)
    column = 25.0 + 0.5 * t + 0.001 * np.sin(t)
    np.testing.assert_allclose(held_samples_smoothed(t, column), column, atol=1e-9)


def test_a_constant_or_nearly_constant_column_is_returned_as_it_is():
    t = np.arange(0.0, 5.0, PERIOD_S)
    np.testing.assert_array_equal(held_samples_smoothed(t, np.full(t.size, 31.25)), 31.25)
    two_steps = np.where(t < 2.5, 25.0, 25.01)
    np.testing.assert_array_equal(held_samples_smoothed(t, two_steps), two_steps)


def test_rows_without_a_temperature_stay_without_one():
    t = np.arange(0.0, 10.0, PERIOD_S)
    held = np.round(_swing(np.floor(t), 0.0), 2)
    held[1000:1200] = np.nan
    smooth = held_samples_smoothed(t, held)
    assert np.isnan(smooth[1000:1200]).all()
    assert np.isfinite(np.delete(smooth, np.s_[1000:1200])).all()


def test_a_temperature_that_stops_moving_stays_flat():
    # reports of the same value for 6 s (the temperature did not move): the spline must not
    # bulge across the plateau as it would with a point only at its first report
    t = np.arange(0.0, 20.0, PERIOD_S)
    truth = np.interp(t, [0, 6, 12, 20], [24.0, 26.0, 26.0, 24.0])
    held = np.round(np.interp(np.floor(t), [0, 6, 12, 20], [24.0, 26.0, 26.0, 24.0]), 2)
    smooth = held_samples_smoothed(t, held)
    plateau = (t > 7.5) & (t < 11.0)
    assert np.abs(smooth[plateau] - truth[plateau]).max() < 0.05


def test_the_diagnosis_input_reads_the_column_through_it():
    t = np.arange(0.0, 10.0, PERIOD_S)
    held = np.round(_swing(np.floor(t), 0.0), 2)
    data = DiagnosisInput(t_s=t, acc_mps2=np.zeros(t.size), valid=np.ones(t.size, bool),
                          lost_before=np.zeros(t.size, int), temp_c=held)
    np.testing.assert_array_equal(data.temperature_c, held_samples_smoothed(t, held))
    assert DiagnosisInput(t_s=t, acc_mps2=np.zeros(t.size), valid=np.ones(t.size, bool),
                          lost_before=np.zeros(t.size, int)).temperature_c is None
