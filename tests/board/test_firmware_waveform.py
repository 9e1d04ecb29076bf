"""The pin waveforms for the simulated board and the pacing of its output (no s51 here)."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.board_protocol import encode_hello, encode_sample_records, encode_status
from drivers.ucsim_board import BoardTimePacer, CpuTime, parse_timer_reports, s51_script
from gateway.core.duty_waveform import StuckInput, pin_events, vcd_lines, waveform_from_counts

TICK_HZ = 921_600


def small_wave():
    return waveform_from_counts(TICK_HZ, [900, 950, 1000], [920, 930, 800], [1852, 1853, 1852], lead_s=0.001)


def test_each_period_rises_together_and_falls_after_its_high_time():
    w = small_wave()
    np.testing.assert_allclose(np.diff(w.start_s) * TICK_HZ, [1852, 1853])
    np.testing.assert_allclose((w.x_fall_s - w.start_s) * TICK_HZ, [900, 950, 1000])
    np.testing.assert_allclose((w.y_fall_s - w.start_s) * TICK_HZ, [920, 930, 800])
    assert w.end_s == pytest.approx(0.001 + (1852 + 1853 + 1852) / TICK_HZ)


def test_counts_that_are_not_a_duty_cycle_are_refused():
    with pytest.raises(ValueError, match="inside its period"):
        waveform_from_counts(TICK_HZ, [1852], [900], [1852])
    with pytest.raises(ValueError, match="positive"):
        waveform_from_counts(TICK_HZ, [1], [1], [0])


def test_pin_events_in_time_order_with_both_rises_at_one_instant():
    events = list(pin_events(small_wave()))
    times = [t for t, _ in events]
    assert times == sorted(times) and len(set(times)) == len(times)
    assert events[0] == (1_000_000, {"x": 1, "y": 1})
    levels = {"x": 0, "y": 0}
    for _, change in events:
        for axis, level in change.items():
            assert level != levels[axis], "every event changes its pin"
            levels[axis] = level


def test_a_stuck_input_holds_its_pin_and_gives_back_the_waveforms_level():
    w = waveform_from_counts(TICK_HZ, [900] * 50, [920] * 50, [1852] * 50)
    stuck = StuckInput("x", start_s=0.010, duration_s=0.0201, level=0)
    x_levels = [(t, c["x"]) for t, c in pin_events(w, (stuck,)) if "x" in c]
    inside = [level for t, level in x_levels if 10_000_000 < t < 30_100_000]
    assert inside == []  # no edge inside the stretch
    at_start = [level for t, level in x_levels if t == 10_000_000]
    assert at_start == [0] or all(level != 1 for t, level in x_levels if 10_000_000 <= t < 30_100_000)
    # after the stretch X toggles again every period
    after = [level for t, level in x_levels if t > 31_000_000]
    assert after[:4] in ([1, 0, 1, 0], [0, 1, 0, 1])
    with pytest.raises(ValueError):
        StuckInput("z", 0, 1, 0)


def test_the_vcd_names_s51s_port_3_pins():
    lines = list(vcd_lines(small_wave()))
    assert "$timescale 1ns $end" in lines
    assert "$var wire 1 ! pin3.2 $end" in lines and '$var wire 1 " pin3.3 $end' in lines
    assert lines[lines.index("#1000000") + 1:lines.index("#1000000") + 3] == ["1!", '1"']


def test_the_pacer_cuts_after_each_sample_at_the_sum_of_the_periods():
    rng = np.random.default_rng(5)
    n = 40
    t2 = rng.integers(1800, 1900, n)
    samples = encode_sample_records(np.arange(n), np.full(n, 900), np.full(n, 920), t2, np.zeros(n, int))
    report = dict(uptime_s=0, tick_hz=TICK_HZ, temp_centi_c=None, fw_major=1, fw_minor=1)
    stream = encode_hello(**report) + b"".join(r.tobytes() for r in samples[:20]) + \
        encode_status(seq=19, **{**report, "uptime_s": 1}) + b"\x00\xa5" + b"".join(r.tobytes() for r in samples[20:])
    pacer = BoardTimePacer(TICK_HZ)
    out = []
    cuts = rng.integers(0, len(stream), 30)
    for piece in np.split(np.frombuffer(stream, np.uint8), np.sort(cuts)):
        out += list(pacer.feed(piece.tobytes()))
    assert len(out) == n
    np.testing.assert_allclose([due for due, _ in out], np.cumsum(t2) / TICK_HZ)
    assert b"".join(chunk for _, chunk in out) + pacer.rest() == stream


def test_s51s_time_reports_are_read_in_order():
    text = """timer get
timer #1("time") ON 0.2 sec (2223636 clks)
timer #2("isr") ON,ISR 0.05 sec (564504 clks)
timer #3("idle") ON,IDLE 0.09 sec (1059072 clks)
timer #4("halt") ON,HALT 0.0 sec (0 clks)
timer #1("time") ON 1.2 sec (13338120 clks)
timer #2("isr") ON,ISR 0.4 sec (4495152 clks)
timer #3("idle") ON,IDLE 0.3 sec (3762564 clks)
timer #4("halt") ON,HALT 0.0 sec (0 clks)
"""
    first, second = parse_timer_reports(text)
    span = second - first
    assert span == CpuTime(11114484, 3930648, 2703492)
    assert span.idle_share == pytest.approx(2703492 / 11114484)
    assert span.main_share == pytest.approx(1 - (3930648 + 2703492) / 11114484)


def test_the_s51_script_stops_on_counts_of_x_falling_edges():
    script = s51_script("b.ihx", "p.vcd", 100, 500).splitlines()
    assert script.index("break 0x0003 100") < script.index("break 0x0003 500") < script.index("quit")
    with pytest.raises(ValueError):
        s51_script("b.ihx", "p.vcd", 0, 5)


def test_board_in_ucsim_refuses_bad_arguments_with_exit_2(tmp_path, capsys):
    from gateway.board_in_ucsim import main

    link = str(tmp_path / "board")
    assert main(["--link", link, "--seconds", "0.1"]) == 2
    assert "too short" in capsys.readouterr().err
    assert main(["--link", link, "--t2-error-frac", "0.9"]) == 2
    with pytest.raises(SystemExit) as stop:
        main(["--link", link, "--stuck", "x:1:nope:0"])
    assert stop.value.code == 2
    assert "AXIS:START_S:DURATION_S:LEVEL" in capsys.readouterr().err
    assert not (tmp_path / "board").exists()


def test_after_a_stuck_stretch_the_pin_takes_the_level_the_waveform_has_then():
    # periods of 1000 ticks, high for the first 500: the stretch ends 0.2 periods into one
    tick_s = 1 / TICK_HZ
    w = waveform_from_counts(TICK_HZ, [500] * 20, [500] * 20, [1000] * 20)
    end_s = 5.2 * 1000 * tick_s
    stuck = StuckInput("x", start_s=2.7 * 1000 * tick_s, duration_s=end_s - 2.7 * 1000 * tick_s, level=0)
    x = [(t, c["x"]) for t, c in pin_events(w, (stuck,)) if "x" in c]
    at_end = [level for t, level in x if abs(t - round(end_s * 1e9)) <= 1]
    assert at_end == [1]  # mid-high: the pin rises where the stretch ends, falls at 5.5 periods
    assert any(abs(t - round(5.5 * 1000 * tick_s * 1e9)) <= 1 and level == 0 for t, level in x)


def test_the_relay_ends_when_the_simulator_dies_before_opening_its_pipe(tmp_path):
    import os
    import threading

    from drivers.pty_port import PtyPort
    from drivers.ucsim_board import relay_paced

    pipe = tmp_path / "uart.pipe"
    os.mkfifo(pipe)
    port = PtyPort()
    result = {}
    relay = threading.Thread(target=lambda: result.update(relay_paced(pipe, port, wait_for_reader_s=0.01,
                                                                      writer_alive=lambda: False)))
    relay.start()
    relay.join(timeout=60)
    port.close()
    assert not relay.is_alive() and result == {"bytes": 0, "samples": 0}
