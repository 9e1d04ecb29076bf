"""The compiled per-chunk sample path against the Python path it replaces.

Two gateways read the same byte stream in the same chunks on the same clock, one with
the compiled path (gateway/sample_fast_path.py), one without; after every chunk the
published values must be equal bit for bit and every counter the same. The stream
has what a serial line brings: motion and standstills, garbage, corrupted frames,
STATUS reports, seq gaps, invalid and clipped samples, a zero period, reserved flags,
samples before the tick rate is known, a board reset, a bias re-estimation command.
"""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from drivers.board_protocol import (
    SAMPLE_FRAME_LENGTH, decode_frames, encode_hello, encode_sample, encode_status,
)
from drivers.published_values import Command
from drivers.sample_scan import sample_at
from gateway.config import validate
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from gateway.daemon import Gateway
from gateway.sample_fast_path import SampleFastPath

REPORT = dict(tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)


def test_the_compiled_path_is_there():
    # numba is a dependency (pyproject.toml): without it the comparison below would
    # compare the Python path with itself
    assert SampleFastPath.available


def test_sample_at_finds_exactly_the_frames_the_decoder_finds():
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
        buf = np.frombuffer(lead + bytes(frame), np.uint8)
        found = sample_at(buf, len(lead))
        decoded = decode_frames(bytes(frame))
        if len(frame) == SAMPLE_FRAME_LENGTH and decoded and type(decoded[0]).__name__ == "Sample" \
                and len(decoded) == 1:
            s = decoded[0]
            assert found == (s.seq, s.t1x_ticks, s.t1y_ticks, s.t2_ticks, s.flags)
        else:
            assert found[0] == -1, (bytes(frame).hex(), decoded)


def board_stream(seed: int) -> tuple[list[bytes], int]:
    """The byte stream in chunks as a serial port hands them over, and the index of the
    chunk after which the PLC asks for a bias re-estimation."""
    rng = random.Random(seed)
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=4))), seed=seed)
    n = min(len(run), 4000)
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
    chunks: list[bytes] = []
    k = 0
    while k < len(frames):
        r = rng.random()
        if r < 0.7:  # one frame per chunk, as a pty delivers the board's writes
            chunks.append(frames[k])
            k += 1
        elif r < 0.9:  # several at once (a busy reader)
            chunks.append(b"".join(frames[k:k + rng.randrange(2, 5)]))
            k = _advance(frames, k, chunks[-1])
        else:  # frames split anywhere
            joined = b"".join(frames[k:k + 3])
            cut = rng.randrange(1, len(joined)) if len(joined) > 1 else 1
            chunks += [joined[:cut], joined[cut:]]
            k = _advance(frames, k, joined)
    assert b"".join(chunks) == b"".join(frames)
    return chunks, len(chunks) // 3


def _advance(frames: list[bytes], k: int, joined: bytes) -> int:
    """Index of the first frame after those `joined` starts with, from k."""
    size = 0
    while size < len(joined):
        size += len(frames[k])
        k += 1
    return k


def gateway(tmp_path, name: str, compiled: bool, clock) -> Gateway:
    cfg = validate({"serial": {"port": str(tmp_path / "no-board")}, "can": {"enabled": False},
                    "state": {"path": str(tmp_path / f"{name}.json")}}, "<test>")
    return Gateway(cfg, clock=clock, compiled_samples=compiled)


def same(a: float, b: float) -> bool:
    return a == b or (a != a and b != b)


def command_at_standstill(tested: Gateway, reference: Gateway, k: int, command_at: int, commanded: bool) -> bool:
    """From chunk `command_at` on, at the first standstill: a bias re-estimation to both
    (accepted, and the next standstill must end it on both). True once it was sent."""
    if commanded or k < command_at or reference._estimate is None or not reference._estimate.standstill:
        return commanded
    assert tested.on_command(Command.REESTIMATE_BIAS, "test")
    assert reference.on_command(Command.REESTIMATE_BIAS, "test")
    return True


def play_to_both(seed: int, now: list[float], tested: Gateway, feed_tested, reference: Gateway):
    """The board stream of `seed`, a chunk every 2 ms of `now`: to `tested` through
    `feed_tested`, to `reference` handled at once, and a bias re-estimation to both at
    the first standstill after the stream's command point. Yields, after each chunk,
    its index, whether it was the last, and whether the command was sent by then."""
    chunks, command_at = board_stream(seed)
    commanded = False
    for k, chunk in enumerate(chunks):
        now[0] += 0.002
        feed_tested(chunk)
        reference.handle_frames(chunk)
        commanded = command_at_standstill(tested, reference, k, command_at, commanded)
        yield k, k == len(chunks) - 1, commanded


def assert_same_values(a, b, where, skip: tuple[str, ...] = ()) -> None:
    for field in a.__dataclass_fields__:
        if field in skip:
            continue
        x, y = getattr(a, field), getattr(b, field)
        assert same(x, y) if isinstance(x, float) else x == y, (where, field, x, y)


@pytest.mark.parametrize("seed", [1, 2])
def test_compiled_and_python_paths_publish_the_same(tmp_path, seed):
    now = [100.0]
    clock = lambda: now[0]  # noqa: E731
    fast = gateway(tmp_path, "fast", True, clock)
    slow = gateway(tmp_path, "slow", False, clock)
    assert fast._fast is not None and slow._fast is None
    taken = [0]
    take = fast._fast.take

    def counting_take(data):
        got = take(data)
        taken[0] += fast._fast.samples if got else 0
        return got

    fast._fast.take = counting_take
    for k, _, commanded in play_to_both(seed, now, fast, fast.handle_frames, slow):
        assert_same_values(fast.values, slow.values, k)
        if fast._estimate is not None:
            assert fast._estimate.bias_estimating == slow._estimate.bias_estimating
            assert fast._estimate.standstill == slow._estimate.standstill
    assert fast.decoder.counters == slow.decoder.counters
    assert fast.session.counters == slow.session.counters
    assert fast.counters == slow.counters
    assert fast.session.timeline.state == slow.session.timeline.state
    for x, y in zip(fast.estimator.kernel_args, slow.estimator.kernel_args):
        assert np.array_equal(x, y, equal_nan=True)
    # the run covered what it claims, and the compiled path did most of the work
    c = slow.decoder.counters
    assert c.samples_lost > 0 and c.crc_errors > 0 and c.bytes_skipped > 0 and c.board_resets == 2
    s = slow.session.counters
    assert s.samples_invalid > 0 and s.samples_saturated > 0 and s.samples_without_tick_rate == 1
    assert s.resets_announced == 1
    assert commanded
    assert taken[0] > 0.8 * slow.counters.samples
    assert math.isfinite(slow.values.position_m)


@pytest.mark.parametrize("seed", [3, 4])
def test_deferred_batches_publish_what_immediate_handling_publishes(tmp_path, seed):
    """`Gateway.receive` keeps bytes until a reader needs the numbers (or MAX_DEFER_S
    passed) and then runs the batch — joined, through the compiled path where it can.
    Whenever anyone looks, it must show what handling every chunk at once, in the
    Python path, shows: same numbers, status and counters, same event times."""
    now = [100.0]
    clock = lambda: now[0]  # noqa: E731
    deferred = gateway(tmp_path, "deferred", True, clock)
    at_once = gateway(tmp_path, "at-once", False, clock)
    rng = random.Random(seed)
    looks = batches = 0
    drain = deferred._drain

    def counting_drain(t, take_waiting=True):
        nonlocal batches
        batches += bool(deferred._inbox)
        drain(t, take_waiting)

    deferred._drain = counting_drain
    for k, last, commanded in play_to_both(seed, now, deferred, deferred.receive, at_once):
        if rng.random() < 0.05 or last:  # a Modbus read, now and then
            looks += 1
            # the heartbeat counts publishes: one per batch instead of one per chunk
            assert_same_values(deferred.values, at_once.values, k, skip=("heartbeat",))
            for name in ("_last_sample_s", "_lost_at", "_saturated_until", "_board_reset_at"):
                assert getattr(deferred, name) == getattr(at_once, name), (k, name)
    assert commanded and looks > 50
    assert deferred.counters == at_once.counters
    assert deferred.decoder.counters == at_once.decoder.counters
    # batches of several chunks really happened (MAX_DEFER_S at 2 ms per chunk: ~5 each)
    assert batches < (k + 1) / 3
