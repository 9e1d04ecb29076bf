"""The one path from board bytes to an estimate (gateway/daemon/sample_pipeline.py).

- compiled and plain Python are the same code under two runners: a fresh interpreter
  with ADXLGW_NO_JIT=1 must give the very same numbers, bit for bit;
- the chunking of the bytes changes nothing;
- it agrees with the offline path (`estimate_series` on the recording's own conversion);
- reports, resets, calibration, clipping and a broken estimator state do what they say.

The stream has what a serial line brings: motion and standstills, garbage, corrupted
frames, STATUS reports, seq gaps, invalid and clipped samples, a zero period, reserved
flags, samples before the tick rate is known, a board reset.
"""
from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.board_decoder import decode_frames
from drivers.board_protocol import (
    SAMPLE_FRAME_LENGTH,
    Sample,
    encode_hello,
    encode_sample,
    encode_status,
    sample_at,
)
from gateway.core import estimator_kernel as K
from gateway.core.conversion import AxisCalibration, Calibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.jit import JIT_ENABLED
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.daemon.sample_pipeline import SamplePipeline

REPO = Path(__file__).resolve().parents[2]
REPORT = dict(tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)
G = STANDARD_GRAVITY_MPS2


UNCALIBRATED = Calibration()  # frozen: one shared default is safe


def pipeline(axis: str = "x", calibration: Calibration = UNCALIBRATED, start_at_rest: bool = True) -> SamplePipeline:
    # the streams here start at rest (a board reset mid-stream still counts as possibly mid-move)
    return SamplePipeline(calibration, from_sensor_model(), axis, start_at_rest=start_at_rest)


def test_sample_at_finds_exactly_the_frames_the_decoder_finds():
    from gateway.core.jit import jit

    compiled_sample_at = jit(sample_at)
    rng = random.Random(5)
    for _ in range(3000):
        fields = [rng.randrange(65536) for _ in range(4)]
        frame = bytearray(encode_sample(*fields, flags=rng.randrange(256)))
        if rng.random() < 0.5:  # one byte changed anywhere, or the frame cut short
            k = rng.randrange(len(frame))
            frame[k] ^= 1 << rng.randrange(8)
        if rng.random() < 0.1:
            frame = frame[: rng.randrange(len(frame))]
        lead = bytes(rng.randrange(256) for _ in range(rng.randrange(3)))
        data = lead + bytes(frame)
        found = sample_at(data, len(lead))  # plain Python, on bytes
        assert compiled_sample_at(np.frombuffer(data, np.uint8), len(lead)) == found  # numba, on an array
        decoded = decode_frames(bytes(frame))
        if len(frame) == SAMPLE_FRAME_LENGTH and decoded and isinstance(decoded[0], Sample) and len(decoded) == 1:
            s = decoded[0]
            assert found == (s.seq, s.t1x_ticks, s.t1y_ticks, s.t2_ticks, s.flags)
        else:
            assert found[0] == -1, (bytes(frame).hex(), decoded)


def board_stream(seed: int, samples: int = 4000) -> list[bytes]:
    """A board's byte stream, frame by frame, with the faults of a real line."""
    rng = random.Random(seed)
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=4))), seed=seed)
    n = min(len(run), samples)
    frames: list[bytes] = [bytes([0x00, 0xA5, 0x13])]  # line noise before the board talks
    frames.append(encode_sample(1, 900, 900, 1843))  # before any STATUS: time unknown
    frames.append(encode_hello(uptime_s=0, **REPORT))
    seq = 0
    for k in range(n):
        t1x, t1y, t2, flags = int(run.t1x[k]), int(run.t1y[k]), int(run.t2[k]), int(run.flags[k])
        r = rng.random()
        if r < 0.004:
            seq += rng.randrange(1, 4)  # samples lost on the line
        elif r < 0.008:
            flags |= 0x01  # x capture timed out
        elif r < 0.010:
            t1x = t2  # 100 % duty: clipped
        elif r < 0.011:
            t2 = 0  # no period measured
        elif r < 0.012:
            flags |= 0x10  # a reserved bit: not protocol version 1
        elif r < 0.013:
            t1x = t2 + 5  # high time longer than the period
        elif r < 0.020 and t2 > 0:
            t1x = round(0.745 * t2) + rng.choice((-1, 0, 1))  # around the clipping limit (1.96 g)
        frame = bytearray(encode_sample(seq & 0xFFFF, t1x, t1y, t2, flags))
        if rng.random() < 0.003:
            frame[rng.randrange(len(frame))] ^= 0x40  # corrupted on the line
        frames.append(bytes(frame))
        if rng.random() < 0.003:
            frames.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30))))
        if k % 500 == 499:
            frames.append(encode_status(seq=seq & 0xFFFF, uptime_s=k // 500, **REPORT))
        if k == n // 2:
            frames.append(encode_hello(uptime_s=0, **REPORT))  # the board reset
            seq = -1
        seq += 1
    return frames


def chunked(frames: list[bytes], seed: int) -> list[bytes]:
    """The stream cut as a serial port might hand it over: a frame, several, or anywhere."""
    rng = random.Random(seed)
    data = b"".join(frames)
    chunks, k = [], 0
    while k < len(data):
        size = rng.choice((SAMPLE_FRAME_LENGTH, 5 * SAMPLE_FRAME_LENGTH, rng.randrange(1, 64)))
        chunks.append(data[k:k + size])
        k += size
    return chunks


def trace(seed: int, chunk_seed: int | None = None, commands: bool = True) -> dict:
    """Feed the stream of `seed` (in chunks from `chunk_seed`, or frame by frame) and record
    after every chunk what a wire would show; with `commands`, a tare at a standstill in
    the first half and a bias re-estimation at one in the second. Plain data, so a
    subprocess can return it."""
    frames = board_stream(seed)
    chunks = frames if chunk_seed is None else chunked(frames, chunk_seed)
    p = pipeline()
    rows = []
    tared = asked = False
    for k, chunk in enumerate(chunks):
        r = p.feed(chunk)
        est = p.latest()
        if commands and est is not None and est.standstill and not tared and k > 100:
            tared = p.tare()
            tared_at = k
        if commands and est is not None and est.standstill and tared and not asked and k > tared_at + 300:
            asked = p.request_bias_reestimate()
        if chunk_seed is None or r.samples:
            rows.append(None if est is None else
                        [est.pos_m, est.vel_mps, est.acc_mps2, est.bias_mps2, est.pos_std_m, est.flags, p.referenced])
    counters = {name: getattr(p.counters, name) for name in p.counters.__slots__}
    decoder = {name: getattr(p.decoder_counters, name) for name in p.decoder_counters.__slots__}
    return {"rows": rows, "counters": counters, "decoder": decoder, "tared": tared, "asked": asked}


def test_compiled_and_plain_python_are_one_implementation_bit_for_bit():
    """The same `run_samples` under numba here and as plain Python in a fresh interpreter
    (ADXLGW_NO_JIT=1): every published number equal to the last bit, every counter equal."""
    assert JIT_ENABLED, "numba is a dependency (pyproject.toml): this must compare compiled with plain"
    here = trace(11)
    code = "import json, sys; from tests.daemon.test_sample_pipeline import trace; json.dump(trace(11), sys.stdout)"
    env = {**os.environ, "ADXLGW_NO_JIT": "1", "PYTHONPATH": str(REPO)}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    plain = json.loads(out.stdout)
    assert here["tared"] and here["asked"], "the stream must exercise tare and bias re-estimation"
    assert plain["counters"] == here["counters"] and plain["decoder"] == here["decoder"]
    assert here["counters"]["resets_announced"] == 1 and here["counters"]["samples_invalid"] > 10
    assert here["counters"]["samples_saturated"] > 10 and here["decoder"]["samples_lost"] > 10
    assert len(plain["rows"]) == len(here["rows"])
    for k, (a, b) in enumerate(zip(here["rows"], plain["rows"], strict=False)):
        assert (a is None) == (b is None), k
        if a is not None:
            for x, y in zip(a, b, strict=False):
                assert x == y or (x != x and y != y), (k, a, b)


@pytest.mark.parametrize("chunk_seed", [1, 2])
def test_how_the_bytes_are_chunked_changes_nothing(chunk_seed):
    one_by_one = trace(12, commands=False)
    cut = trace(12, chunk_seed, commands=False)
    assert cut["counters"] == one_by_one["counters"] and cut["decoder"] == one_by_one["decoder"]
    last = [row for row in one_by_one["rows"] if row is not None][-1]
    assert [row for row in cut["rows"] if row is not None][-1] == last


def test_the_pipeline_and_the_offline_estimate_agree():
    """Frames through the daemon's pipeline, sample by sample, against `estimate_series`
    on the same recording converted the offline way (sample_times_s, acceleration_mps2)."""
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=3))), seed=4)
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **{**REPORT, "tick_hz": int(run.tick_hz)}))
    pos = []
    for k in range(len(run)):
        p.feed(encode_sample(k & 0xFFFF, int(run.t1x[k]), int(run.t1y[k]), int(run.t2[k]), int(run.flags[k])))
        pos.append(p.latest().pos_m)
    t = sample_times_s(run.t2, run.tick_hz)
    acc = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    track = estimate_series(t, acc, method="realtime", settings=from_sensor_model(), lost_before=np.zeros(t.size))
    np.testing.assert_array_equal(np.array(pos), track.pos_m)


def test_waits_for_the_tick_rate_then_times_and_converts():
    p = pipeline()
    r = p.feed(encode_sample(0, 921, 925, 1843))
    assert r.samples == 0 and p.counters.samples_without_tick_rate == 1 and p.latest() is None
    p.feed(encode_status(seq=0, uptime_s=0, **{**REPORT, "temp_centi_c": 2512}))
    r = p.feed(encode_sample(1, 921, 925, 1843) + encode_sample(4, 921, 925, 1843))
    assert r.samples == 2 and r.samples_lost == 2
    assert p.board.temp_c == pytest.approx(25.12) and p.board.tick_hz == 921_600
    est = p.latest()
    assert est.t_s == pytest.approx(3 * 1843 / 921_600)  # two lost periods before the second


def test_axis_calibration_validity_and_clipping():
    cal = Calibration(y=AxisCalibration(0.51, 0.12))
    p = pipeline("y", cal)
    p.feed(encode_hello(uptime_s=0, **REPORT))
    assert p.feed(encode_sample(0, 100, 1843 * 63 // 100, 1843)).invalid == 0
    r = p.feed(encode_sample(1, 921, 925, 1843, flags=0x02))  # y capture timed out
    assert r.invalid == 1 and r.saturated == 0
    assert p.feed(encode_sample(2, 921, int(1843 * 0.76), 1843)).saturated == 1
    assert p.feed(encode_sample(3, 921, 925, 1843, flags=0x01)).invalid == 0  # x's flag: y is fine
    assert p.counters.samples == 4 and p.counters.samples_invalid == 1


def test_first_hello_is_power_on_later_ones_and_uptime_going_back_are_resets():
    p = pipeline()
    assert not p.feed(encode_hello(uptime_s=0, **REPORT)).board_reset
    p.feed(encode_status(seq=10, uptime_s=50, **REPORT) + encode_sample(11, 921, 925, 1843))
    assert p.feed(encode_hello(uptime_s=0, **REPORT)).board_reset
    p.feed(encode_status(seq=10, uptime_s=60, **REPORT))
    assert p.feed(encode_status(seq=10, uptime_s=3, **REPORT)).board_reset  # HELLO lost on the line
    assert (p.counters.resets_announced, p.counters.resets_inferred) == (1, 1)
    p.feed(encode_sample(0, 921, 925, 1843))
    assert p.latest().t_s == 0.0  # time starts over


def at_rest(p: SamplePipeline, seq0: int, n: int) -> int:
    for k in range(n):
        p.feed(encode_sample((seq0 + k) & 0xFFFF, 921, 921, 1843))
    return seq0 + n


def accelerate(p: SamplePipeline, seq0: int, g: float, n: int) -> int:
    """n samples of a constant acceleration (g) on x."""
    t1 = round((0.5 + g * 0.125) * 1843)
    for k in range(n):
        p.feed(encode_sample((seq0 + k) & 0xFFFF, t1, 921, 1843))
    return seq0 + n


def test_tare_references_and_a_reset_keeps_the_position_but_not_the_reference():
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **REPORT))
    assert not p.tare()  # nothing estimated yet
    seq = at_rest(p, 0, 200)
    assert p.latest().standstill and not p.referenced
    assert p.tare() and p.referenced and p.latest().pos_m == 0.0
    seq = accelerate(p, accelerate(p, seq, 0.3, 50), -0.3, 50)  # a move that ends at rest
    seq = at_rest(p, seq, 300)
    moved = p.latest().pos_m
    assert abs(moved) > 0.01 and p.latest().standstill
    assert p.feed(encode_hello(uptime_s=0, **REPORT)).board_reset
    assert p.latest() is None and not p.referenced
    at_rest(p, 0, 200)
    # continuous (to the drift of a filter that restarted with its velocity unknown), not
    # referenced, and not trusted: the board may have reset mid-move
    assert p.latest().pos_m == pytest.approx(moved, abs=1e-5)
    assert not p.referenced and p.latest().untrusted


def test_a_start_over_and_a_restored_start_keep_the_position_no_more_certain_than_it_was():
    """The new estimator starts with a position variance 0; the position it continues from
    is not exact: its σ before the reset (or a restored position's σ) stays in the published one."""
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **REPORT))
    seq = at_rest(p, 0, 200)
    seq = accelerate(p, accelerate(p, seq, 0.3, 50), -0.3, 50)
    at_rest(p, seq, 300)
    before = p.latest().pos_std_m
    assert before > 0.0
    p.feed(encode_hello(uptime_s=0, **REPORT))
    at_rest(p, 0, 200)
    assert p.latest().pos_std_m >= before
    p.set_start_uncertainty(0.5)  # a restored position, 0.25 s unwatched at 2 m/s
    filter_var_m2 = float(p.estimator.state.out[K.O_POS_VAR])
    # the two variances add (independent errors); the filter's own state is left as it was
    assert p.latest().pos_std_m == pytest.approx(math.sqrt(filter_var_m2 + 0.25), rel=1e-12)
    assert p.estimator.state.out[K.O_POS_VAR] == filter_var_m2
    assert p.tare() and p.reference_var_m2 == 0.0  # here is zero by definition


def test_bias_reestimation_only_at_standstill_and_flagged_until_the_next_stop():
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **REPORT))
    seq = at_rest(p, 0, 200)
    assert not p.latest().bias_estimating
    assert p.request_bias_reestimate()
    seq = at_rest(p, seq, 10)
    assert p.latest().bias_estimating
    seq = accelerate(p, seq, 0.3, 50)
    assert not p.request_bias_reestimate()  # in motion: declined
    seq = accelerate(p, seq, -0.3, 50)
    at_rest(p, seq, 300)
    assert p.latest().standstill and not p.latest().bias_estimating


def test_a_diverged_estimator_is_flagged_counted_and_started_over():
    """1.9 g held for a minute (a stuck sensor reading, no stop): the velocity passes any
    machine's; the state is declared broken, counted, and the estimator starts over."""
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **REPORT))
    seq = at_rest(p, 0, 200)
    fault = False
    for _ in range(60 * 10):
        before = p.counters.estimator_faults
        seq = accelerate(p, seq, 1.9, 50)
        fault = p.counters.estimator_faults > before
        if fault:
            break
    assert fault and p.counters.estimator_faults == 1 and not p.referenced


def test_the_kernel_flags_a_non_finite_state():
    settings = from_sensor_model()
    prm = settings.kernel_params()
    state = K.new_state(prm)
    for k in range(100):
        K.step(state, prm, k * 0.002, 0.0, True, 0)
    assert not int(state.out[K.O_FLAGS]) & K.F_FAULT
    K.step(state, prm, 0.2, math.inf, True, 0)  # an infinite input is invalid, not a fault
    assert not int(state.out[K.O_FLAGS]) & K.F_FAULT
    state.x[0] = math.nan  # memory corrupted
    K.step(state, prm, 0.202, 0.0, True, 0)
    assert int(state.out[K.O_FLAGS]) & K.F_FAULT


def test_a_seq_that_steps_back_costs_no_time():
    """A board that restarted without its HELLO reaching us: seq starts again low. Read as
    a gap it would put ~2 minutes into one step; it is counted and costs one period."""
    p = pipeline()
    p.feed(encode_hello(uptime_s=0, **REPORT))
    at_rest(p, 5000, 100)
    before = p.latest().t_s
    r = p.feed(encode_sample(3, 921, 921, 1843))
    assert r.samples_lost == 0 and p.decoder_counters.seq_backwards == 1
    assert p.latest().t_s == pytest.approx(before + 1843 / 921_600)


def test_before_the_first_estimate_the_position_is_untrusted_unless_known_to_start_at_rest():
    """A daemon restarted (or a board reset) mid-move shows its last saved position before
    any sample is estimated: the wires must not wait for the first window to say that
    position is not trustworthy (the fault benchmark's restart showed it 0.5 s late)."""
    from drivers.published_values import StatusBits
    from gateway.daemon.board_intake import BoardIntake
    from gateway.daemon.status_flags import LinkHealth

    health = LinkHealth(port_open=True, last_byte_s=0.0, stale_after_s=0.2, lost_after_s=1.0)
    for at_rest, untrusted in ((False, True), (True, False)):
        intake = BoardIntake(pipeline(start_at_rest=at_rest))
        assert intake.pipeline.latest() is None
        intake.publish(0.0)
        status = intake.snapshot(health).status
        assert (StatusBits.POSITION_UNTRUSTED in status) is untrusted
        assert StatusBits.VALID not in status
    # a board reset starts over with the velocity unknown: untrusted at once
    intake = BoardIntake(pipeline(start_at_rest=True))
    intake.pipeline.reset()
    intake.publish(0.0)
    assert StatusBits.POSITION_UNTRUSTED in intake.snapshot(health).status


def test_the_published_sigma_never_exceeds_the_distance_to_the_farther_end_of_the_travel():
    """After a board reset the velocity is unknown and the filter's σ grows without bound
    (the fault benchmark: 25 m within 20 s on a 20 m travel); the axis cannot leave its
    travel, so no position it can have is farther from the estimate than the farther end."""
    def reset_then_quiet(p: SamplePipeline) -> None:
        p.feed(encode_hello(uptime_s=0, **REPORT))
        seq = at_rest(p, 0, 200)
        seq = accelerate(p, accelerate(p, seq, 0.3, 50), -0.3, 50)
        at_rest(p, seq, 100)
        p.feed(encode_hello(uptime_s=0, **REPORT))  # a board reset: the velocity is lost
        at_rest(p, 0, 2000)  # 4 s it cannot tell from a cruise (one at the floor speed lasts 5 s on 0.5 m)

    unbounded = pipeline()
    reset_then_quiet(unbounded)
    bounded = pipeline()
    bounded.set_travel((-0.2, 0.3))
    reset_then_quiet(bounded)
    est, free = bounded.latest(), unbounded.latest()
    farthest = max(est.pos_m + 0.2, 0.3 - est.pos_m)
    assert free.pos_std_m > farthest  # the case the bound is for
    assert est.pos_std_m == pytest.approx(farthest) and est.pos_m == free.pos_m
    bounded.set_travel((-10.0, 10.0))  # a reload: the new travel from the next read on
    assert bounded.latest().pos_std_m == pytest.approx(min(free.pos_std_m, 10.0 + abs(est.pos_m)))


def test_a_seq_gap_longer_than_an_outage_starts_over_at_the_gap_a_short_one_is_bridged():
    """The board's seq and period say how long the line lost samples: beyond OUTAGE_S the
    axis may have moved meanwhile (the estimator starts over with the velocity unknown, the
    position continuous but no longer referenced); a gap of a few samples is bridged."""
    from gateway.daemon.sample_loop import OUTAGE_S

    period_s = 1843 / 921_600
    short_gap = 10
    long_gap = int(OUTAGE_S / period_s) + 20
    for gap, starts_over in ((short_gap, False), (long_gap, True)):
        p = pipeline()
        p.feed(encode_hello(uptime_s=0, **REPORT))
        seq = at_rest(p, 0, 200)
        assert p.tare()
        seq = accelerate(p, seq, 0.3, 50)
        before = p.latest().pos_m
        # the gap, then the samples after it in one chunk: the start-over comes at the gap
        r = p.feed(b"".join(encode_sample((seq + gap + k) & 0xFFFF, 921, 921, 1843) for k in range(5)))
        assert r.samples == 5 and r.samples_lost == gap
        assert (r.outage_s > 0.0) is starts_over
        assert p.referenced is not starts_over
        if starts_over:
            assert r.outage_s == pytest.approx(gap * period_s)
            assert p.latest().untrusted and p.latest().pos_m == pytest.approx(before, abs=0.01)


def test_a_backlog_read_late_keeps_the_estimate_a_silence_the_seq_cannot_account_for_does_not():
    """A host that fell behind (a loaded machine, a slow VM) reads the board's backlog at once:
    the seq runs on, nothing was lost, the estimate and its reference stay. A silence longer
    than a whole wrap of the 16-bit seq at the fastest board could hide lost samples."""
    from gateway.daemon.board_intake import SEQ_PROVES_CONTINUITY_S, BoardIntake

    for late_s, starts_over in ((10.0, False), (SEQ_PROVES_CONTINUITY_S + 1.0, True)):
        intake = BoardIntake(pipeline())
        p = intake.pipeline
        intake.receive(0.0, encode_hello(uptime_s=0, **REPORT))
        intake.receive(0.0, b"".join(encode_sample(k, 921, 921, 1843) for k in range(200)))
        intake.drain()
        assert p.tare()
        intake.receive(late_s, b"".join(encode_sample(200 + k, 921, 921, 1843) for k in range(50)))
        assert intake.drain()
        assert p.referenced is not starts_over
        assert (intake.events.outage_at_s is not None) is starts_over


def test_the_travel_bounds_how_long_a_quiet_stretch_may_be_a_cruise():
    """With the velocity lost (a board reset) a quiet stretch is a stop only once no cruise
    at the speed floor could have lasted that long within the axis's travel: the travel
    given at start and at a reload reaches the estimator."""
    def quiet_after_a_reset(p: SamplePipeline, samples: int) -> bool:
        p.feed(encode_hello(uptime_s=0, **REPORT))
        at_rest(p, 0, 200)
        p.feed(encode_hello(uptime_s=0, **REPORT))  # a board reset: the velocity is lost
        at_rest(p, 0, samples)
        return p.latest().standstill

    floor = from_sensor_model().standstill_speed_floor_mps
    short = pipeline()
    short.set_travel((-0.2, 0.2))  # a cruise at the floor lasts ≤ 4 s
    assert short.estimator.settings.quiet_stop_s == pytest.approx(0.4 / floor)
    assert quiet_after_a_reset(short, 2500)  # 5 s of quiet: a stop
    long = pipeline()
    long.set_travel((-0.5, 0.5))  # ≤ 10 s: 5 s of quiet may still be a cruise
    assert not quiet_after_a_reset(long, 2500)
    long.set_travel((-0.1, 0.1))  # a reload: from now on ≤ 2 s
    at_rest(long, 2500, 1500)
    assert long.latest().standstill
