"""The own simulator's buffering USB adapter (sensor_effects.TimingTerm): what the FTDI
data sheets and AN232B-04 say it does, checked on the arrivals it makes."""
import numpy as np

from gateway.core.sensor_effects import USB_PACKET_DATA_BYTES, TimingTerm, buffered_arrivals_s
from gateway.core.sensor_model import BOARD_HOST_LINK
from testing.diagnosis_cases import SENSOR, make_case

PERIOD_S = SENSOR.t2_s
DONE_S = np.arange(2000) * PERIOD_S + BOARD_HOST_LINK.frame_time_s


def _arrivals(latency_timer_s):
    return buffered_arrivals_s(DONE_S, BOARD_HOST_LINK.frame_bytes, BOARD_HOST_LINK.baud, latency_timer_s,
                               USB_PACKET_DATA_BYTES, 0.3e-3)


def test_a_short_latency_timer_sends_every_timer_period():
    sent = _arrivals(0.004)
    wait = sent - DONE_S
    assert wait.min() >= 0.0 and wait.max() <= 0.004 + 1e-12
    # frames go in groups, each group leaving when the timer expires: on its grid
    assert np.allclose(((sent + 0.3e-3) / 0.004) % 1.0 * (1 - ((sent + 0.3e-3) / 0.004) % 1.0), 0.0, atol=1e-9)
    assert 0.3 < np.mean(np.diff(sent) == 0) < 0.8


def test_a_long_latency_timer_leaves_the_packets_to_fill():
    sent = _arrivals(0.016)
    wait = (sent - DONE_S)[:-20]  # the last packet leaves when the timer expires at the end
    # a packet fills with 62 bytes: at most 5 frames of 15 bytes wait for it, never the timer
    assert wait.max() <= 5 * PERIOD_S
    assert 0.6 < np.mean(np.diff(sent) == 0) < 0.85  # 4 or 5 frames leave together


def test_a_clock_step_back_makes_arrival_times_go_backwards():
    _, data = make_case(("timing",), 0, adjust=lambda t: TimingTerm(0.008, clock_step_s=-0.02, step_at=0.5))
    steps = np.diff(data.t_host_s)
    assert np.count_nonzero(steps < 0) == 1
    assert steps.min() < -0.01
    assert np.count_nonzero(steps == 0) > 0.3 * steps.size  # frames of one packet stamped at once
