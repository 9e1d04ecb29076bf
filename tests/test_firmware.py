"""The board's firmware (firmware/), built with SDCC and run in s51 on the waveforms of the
paper scenario: its frames, its timing against the waveform, its CPU budget, and the
gateway's position from its stream against the Python emulator's.

The run is s51's simulated time, not the host's: nothing here depends on how loaded the
machine is (the waits are generous). sdcc and sdcc-ucsim come from
scripts/apt-test-packages.txt; without them these tests fail, they do not skip.
"""
from __future__ import annotations

import numpy as np
import pytest

from drivers.board_protocol import Hello, Sample, Status, StreamDecoder
from gateway.board_in_ucsim import WARMUP_PERIODS, BoardRunSettings, run_board_to_file
from gateway.core.conversion import AxisCalibration, acceleration_mps2, axis_valid, lost_before_from_seq, sample_times_s
from gateway.core.duty_waveform import StuckInput
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import rest_intervals
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate

pytestmark = pytest.mark.slow

SEED = 7
TICK_HZ = 921_600
# s51 is given this long per run; it needs ~1/2.6 of the board time on an idle core
S51_TIMEOUT_S = 900
# The protocol's goal for the timing: within 2 ticks of the waveform (docs/board-link.md)
TIMING_TOLERANCE_TICKS = 2
# Position at the paper's 10th stop, firmware stream against the emulator's: the two
# streams carry the same counts but for T2 (timed over 32 periods on the board, each
# period's own in the emulator), so they may differ by far less than the paper's 1 mm
POSITION_TOLERANCE_M = 1e-3


class Stream:
    def __init__(self, data: bytes):
        self.decoder = StreamDecoder()
        self.frames = self.decoder.feed(data)
        samples = [f for f in self.frames if isinstance(f, Sample)]
        self.seq = np.array([s.seq for s in samples])
        self.t1x = np.array([s.t1x_ticks for s in samples])
        self.t1y = np.array([s.t1y_ticks for s in samples])
        self.t2 = np.array([s.t2_ticks for s in samples])
        self.flags = np.array([s.flags for s in samples])

    def __len__(self) -> int:
        return int(self.seq.size)


def first_period(stream: Stream, wave_t1x: np.ndarray, search: int = 200) -> int:
    """The waveform period of the firmware's first sample: the offset where the X counts
    agree best (the start-up before the first sample takes a few tens of periods)."""
    ok = (stream.flags & 1) == 0
    n = min(len(stream), wave_t1x.size - search)
    errors = [np.mean(np.abs(stream.t1x[:n][ok[:n]] - wave_t1x[p:p + n][ok[:n]])) for p in range(search)]
    return int(np.argmin(errors))


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    duration_s = build_profile(ScenarioSettings()).duration_s
    settings = BoardRunSettings(seed=SEED, board_s=duration_s - 0.1)
    record = run_board_to_file(settings, tmp_path_factory.mktemp("paper"), timeout_s=S51_TIMEOUT_S)
    return settings, record, Stream(record.uart_bytes)


def test_the_frames_decode_without_an_error_or_a_lost_sample(paper_run):
    settings, record, stream = paper_run
    c = stream.decoder.counters
    assert (c.crc_errors, c.length_errors, c.unknown_types, c.bytes_skipped, c.samples_lost) == (0, 0, 0, 0, 0)
    assert isinstance(stream.frames[0], Hello) and stream.frames[0].tick_hz == TICK_HZ
    assert c.hellos_decoded == 1
    assert stream.seq[0] == 0 and np.all(np.diff(stream.seq) == 1)
    # s51 stopped at its last X falling edge: every period after the start-up has its sample
    assert len(stream) >= settings.periods - WARMUP_PERIODS
    board_s = stream.t2.sum() / TICK_HZ
    statuses = [f for f in stream.frames if isinstance(f, Status)]
    assert len(statuses) == int(board_s)  # one per second of the board's clock
    assert [s.uptime_s for s in statuses] == list(range(1, len(statuses) + 1))


def test_t1x_t1y_and_t2_are_the_waveforms_within_two_ticks(paper_run):
    _, record, stream = paper_run
    wave = record.waveform
    p0 = first_period(stream, wave.t1x_ticks)
    n = len(stream)
    x_ok = (stream.flags & 1) == 0
    y_ok = (stream.flags & 2) == 0
    assert x_ok.all()  # X is never stuck here; Y gives a span every 1024 periods to T2
    err_x = stream.t1x - wave.t1x_ticks[p0:p0 + n]
    err_y = (stream.t1y - wave.t1y_ticks[p0:p0 + n])[y_ok]
    err_t2 = stream.t2 - wave.t2_ticks[p0:p0 + n]
    for name, err in (("t1x", err_x), ("t1y", err_y), ("t2", err_t2)):
        assert np.max(np.abs(err)) <= TIMING_TOLERANCE_TICKS, f"{name}: worst {np.max(np.abs(err))} ticks"
    # Y is not measured while its timer times T2: 32 of every 1024 + 34 periods
    assert 0 < np.count_nonzero(~y_ok) <= np.ceil(n / (1024 + 34)) * 32 + 32
    # the board's clock (the sum of the T2 sent) keeps the waveform's time
    drift_ticks = stream.t2.sum() - wave.t2_ticks[p0:p0 + n].sum()
    assert abs(drift_ticks) <= TIMING_TOLERANCE_TICKS * 32, f"board clock off by {drift_ticks} ticks"


def test_the_idle_share_at_500_samples_per_s_is_at_least_a_quarter(paper_run):
    # s51's cycle counts (simulated, not the host's time): the goal of issue 33
    _, record, _ = paper_run
    budget = record.s51.measured
    assert budget.idle_share >= 0.25, f"idle {budget.idle_share:.3f}"
    assert 0 < budget.isr_share < 1 and 0 < budget.main_share < 1


def _position_at(times_t2, t1x, flags, seq, index):
    lost = lost_before_from_seq(seq)
    t = sample_times_s(times_t2, TICK_HZ, lost)
    acc = acceleration_mps2(t1x, times_t2, AxisCalibration())
    valid = axis_valid(flags, t1x, times_t2, "x")
    # the raw recording's default: the sensor model's settings (adxlgw estimate without a drift fit)
    track = estimate_series(t, acc, valid, method="realtime", settings=from_sensor_model(SensorParams()),
                            lost_before=lost)
    return float(track.pos_m[index])


def test_the_position_at_the_tenth_stop_matches_the_emulators(paper_run):
    settings, record, stream = paper_run
    truth = simulate(build_profile(settings.scenario), settings.sensor, seed=SEED)
    wave = record.waveform
    assert np.array_equal(wave.t1x_ticks[:len(truth)], truth.t1x[:wave.t1x_ticks.size])
    p0 = first_period(stream, wave.t1x_ticks)
    stops = rest_intervals(truth.t_s, truth.ref_vel_mps)
    start, stop = stops[10]  # 0 is the initial rest; the 10th stop follows the 10th stroke
    at = min(stop - 1, p0 + len(stream) - 1)
    assert at > start + 50, "the run ends before the 10th stop"
    n_emu = at + 1
    emulator_m = _position_at(truth.t2[:n_emu], truth.t1x[:n_emu], truth.flags[:n_emu], truth.seq[:n_emu], at)
    firmware_m = _position_at(stream.t2, stream.t1x, stream.flags, stream.seq, at - p0)
    assert abs(firmware_m - emulator_m) <= POSITION_TOLERANCE_M, (firmware_m, emulator_m)
    # and both are near the truth there (the estimate works on this stream at all)
    assert abs(emulator_m - truth.ref_pos_m[at]) < 0.03


@pytest.fixture(scope="module")
def stuck_run(tmp_path_factory):
    stuck = (
        StuckInput("x", start_s=0.500, duration_s=0.100, level=0),
        StuckInput("x", start_s=0.800, duration_s=0.030, level=1),
        StuckInput("y", start_s=1.000, duration_s=0.050, level=0),
        StuckInput("y", start_s=1.300, duration_s=0.100, level=1),  # overflows Timer 1: > 71 ms
    )
    settings = BoardRunSettings(seed=SEED, board_s=1.6, stuck=stuck)
    record = run_board_to_file(settings, tmp_path_factory.mktemp("stuck"), timeout_s=S51_TIMEOUT_S)
    return settings, record, Stream(record.uart_bytes)


def test_a_stuck_input_sets_its_timeout_flag_and_the_next_good_period_recovers(stuck_run):
    settings, record, stream = stuck_run
    c = stream.decoder.counters
    assert (c.crc_errors, c.samples_lost) == (0, 0)
    assert np.all(np.diff(stream.seq) == 1)  # one sample per period, stuck or not
    wave = record.waveform
    t_start = wave.start_s  # each sample's period in the waveform
    p0 = first_period(stream, wave.t1x_ticks)
    periods = p0 + np.arange(len(stream))
    start_s = t_start[periods]
    end_s = start_s + wave.t2_ticks[periods] / TICK_HZ
    for s in settings.stuck:
        bit = 1 if s.axis == "x" else 2
        t1 = stream.t1x if s.axis == "x" else stream.t1y
        truth = (wave.t1x_ticks if s.axis == "x" else wave.t1y_ticks)[periods]
        inside = (start_s >= s.start_s) & (end_s <= s.start_s + s.duration_s)
        assert inside.sum() >= 10
        assert np.all(stream.flags[inside] & bit), f"{s}: a period inside the stretch was not flagged"
        # the first whole period after the stretch is measured again, and right
        after = int(np.argmax(start_s >= s.start_s + s.duration_s))
        assert stream.flags[after] & bit == 0, f"{s}: the period after the stretch is still flagged"
        assert abs(int(t1[after]) - truth[after]) <= TIMING_TOLERANCE_TICKS
        # the other axis keeps being measured through the stretch (but Y's T2 spans)
        other = 2 if bit == 1 else 1
        if other == 1:
            assert not np.any(stream.flags[inside] & other)
