"""The daemon's per-chunk sample path in one compiled call: bytes → estimator.

What `Gateway.handle_frames` does per SAMPLE through the Python objects — decode
(`StreamDecoder.feed`), time and convert (`BoardSession.on_sample`), estimate
(`EstimatorLink.step`) — done for a whole chunk in one numba call, on the very same
state: the decoder's seq continuity, the session's timeline and calibration, the
estimator kernel's arrays. Why: on a VM the gateway is woken 500 times a second, and
each wakeup runs its Python cold — about ten times slower than in a loop; one
compiled call per chunk touches far less (benchmarks/daemon_hot_path.py,
docs/daemon.md).

Only the common case is taken: whole, CRC-valid SAMPLE frames from the start of the
chunk, while the decoder buffers nothing and the board's tick rate is known. At the
first byte that is anything else (garbage, a partial frame, STATUS, HELLO) the call
stops and the rest of the chunk goes through the Python path, which continues from
exactly the state the compiled path left. tests/test_sample_fast_path.py feeds one
byte stream (garbage, reports, gaps, invalid and clipped samples, a board reset,
random chunking) to a gateway with and without this path and requires the same
published numbers, bit for bit, and the same counters.

Without numba (or with ADXLGW_NO_JIT=1) the path is off: the Python path alone is
faster than this function run as plain Python.
"""
from __future__ import annotations

import math

import numpy as np

from drivers.board_protocol import (
    FLAG_TIMER_OVERFLOW, FLAG_X_TIMED_OUT, FLAG_Y_TIMED_OUT, FLAGS_RESERVED, SAMPLE_FRAME_LENGTH, StreamDecoder,
)
from drivers.sample_scan import COMPILED, sample_at
from gateway.board_session import SATURATION_FRACTION, BoardSession
from gateway.core import estimator_kernel as K
from gateway.core.jit import JIT_ENABLED, jit
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.estimation_link import EstimatorLink

# ---- the one float64 array that carries state in and results out ------------------
S_LAST_SEQ = 0  # decoder: seq of the last SAMPLE/HELLO, −1 before any
S_HAS_NEXT = 1  # timeline: 1 once a sample was timed
S_NEXT_T = 2  # timeline: time of the next sample (s)
S_LAST_PERIOD = 3  # timeline: last period (s)
S_TICK_HZ = 4
S_ZERO_G = 5  # calibration of the configured axis: zero-g duty cycle
S_SENS = 6  # … and sensitivity (duty per g)
S_SAT_LIMIT = 7  # |acceleration| at or above this is clipped (m/s²)
S_VALID_MASK = 8  # flags that make the configured axis' counts invalid
S_AXIS_Y = 9  # 1: the configured axis is y
R_SAMPLES = 10
R_LOST = 11  # samples lost (seq gaps) …
R_GAPS = 12  # … in how many gaps
R_INVALID = 13
R_SATURATED = 14
R_LAST_LOST = 15  # which sample of the run (0-based) last had samples lost before it, −1: none
R_LAST_SATURATED = 16  # which sample of the run was last clipped, −1: none
R_ENTRY = 17  # 1: some step began a standstill
N_SLOTS = 18

_FRAME = SAMPLE_FRAME_LENGTH
_G = STANDARD_GRAVITY_MPS2
_F_ENTRY = K.F_ENTRY
_O_FLAGS = K.O_FLAGS
_CLIPPED_FLAGS = FLAG_X_TIMED_OUT | FLAG_Y_TIMED_OUT | FLAG_TIMER_OVERFLOW
_X_INVALID = FLAG_X_TIMED_OUT | FLAG_TIMER_OVERFLOW | FLAGS_RESERVED
_Y_INVALID = FLAG_Y_TIMED_OUT | FLAG_TIMER_OVERFLOW | FLAGS_RESERVED


@jit
def run_chunk(buf, st, x, P, m, ring_z, ring_ok, snap, prm, gain, out):
    """The leading good SAMPLE frames of `buf` through decoder, session and kernel.

    Each step is the Python path's, operation for operation (same float arithmetic
    in the same order): StreamDecoder.feed's seq continuity, SampleTimeline.advance,
    BoardSession.on_sample's conversion and clipping, EstimatorLink.step's kernel
    call. Returns the bytes taken; state and results in `st` (layout S_*, R_*).
    """
    pos = 0
    n = 0
    last_seq = np.int64(st[S_LAST_SEQ])
    has_next = st[S_HAS_NEXT] > 0.0
    next_t = st[S_NEXT_T]
    last_period = st[S_LAST_PERIOD]
    tick_hz = st[S_TICK_HZ]
    zero_g = st[S_ZERO_G]
    sens = st[S_SENS]
    sat_limit = st[S_SAT_LIMIT]
    invalid_mask = np.int64(st[S_VALID_MASK])
    use_y = st[S_AXIS_Y] > 0.0
    lost_total = 0
    gaps = 0
    invalid = 0
    saturated_n = 0
    last_lost = -1
    last_saturated = -1
    entry = False
    while True:
        seq, t1x, t1y, t2, flags = sample_at(buf, pos)
        if seq < 0:
            break
        pos += _FRAME
        n += 1
        # decoder: samples lost before this one
        lost = 0
        if last_seq >= 0:
            lost = (seq - last_seq - 1) & 0xFFFF
            if lost:
                lost_total += lost
                gaps += 1
        last_seq = seq
        # session: the sample's time
        if t2 > 0:
            period = t2 / tick_hz
        elif has_next:
            period = last_period
        else:
            period = 0.0
        t_s = next_t + lost * last_period if has_next else 0.0
        last_period = period
        next_t = t_s + period
        has_next = True
        # session: acceleration along the axis, validity, clipping
        t1 = t1y if use_y else t1x
        acc = math.nan
        if (flags & invalid_mask) == 0 and t2 > 0 and 0 <= t1 <= t2:
            acc = (t1 / t2 - zero_g) / sens * _G
        saturated = (flags & _CLIPPED_FLAGS) != 0
        ok = math.isfinite(acc)
        if not ok:
            invalid += 1
        else:
            if abs(acc) >= sat_limit:
                saturated = True
            if saturated:
                saturated_n += 1
        if lost:
            last_lost = n - 1
        if saturated:
            last_saturated = n - 1
        # estimator
        K.step(x, P, m, ring_z, ring_ok, snap, prm, gain, t_s, acc if ok else 0.0, ok, lost, out)
        if np.int64(out[_O_FLAGS]) & _F_ENTRY:
            entry = True
    st[S_LAST_SEQ] = last_seq
    st[S_HAS_NEXT] = 1.0 if has_next else 0.0
    st[S_NEXT_T] = next_t
    st[S_LAST_PERIOD] = last_period
    st[R_SAMPLES] = n
    st[R_LOST] = lost_total
    st[R_GAPS] = gaps
    st[R_INVALID] = invalid
    st[R_SATURATED] = saturated_n
    st[R_LAST_LOST] = last_lost
    st[R_LAST_SATURATED] = last_saturated
    st[R_ENTRY] = 1.0 if entry else 0.0
    return pos


class SampleFastPath:
    """`take(data)` runs the leading SAMPLE frames of a chunk through `run_chunk` and
    writes the state back to the decoder, session and estimator link it serves."""

    available = JIT_ENABLED and COMPILED

    def __init__(self, decoder: StreamDecoder, session: BoardSession, link: EstimatorLink):
        self.decoder = decoder
        self.session = session
        self.link = link
        self._st = np.zeros(N_SLOTS)
        # the results of the last take, as the daemon reads them
        self.samples = 0
        self.last_lost = -1  # the sample of the run (0-based) that last had a gap before it, −1: none
        self.last_saturated = -1  # … that was last clipped
        self.entered_standstill = False
        # compile (or load from numba's cache) now, before the daemon reports READY
        run_chunk(np.zeros(0, np.uint8), np.zeros(N_SLOTS), *link.kernel_args, link.kernel_out)

    @property
    def ready(self) -> bool:
        """False while the Python path must go on: bytes buffered in the decoder (a
        frame split across chunks), or the board's tick rate not known yet."""
        return self.session.tick_hz is not None and not self.decoder.buffered_bytes

    def take(self, data: bytes) -> int:
        """Bytes of `data` taken (whole SAMPLE frames from its start); 0: none, the
        Python path has it all (see `ready`)."""
        if not self.ready:
            return 0
        session = self.session
        decoder = self.decoder
        st = self._st
        st[S_LAST_SEQ] = decoder.last_seq
        timeline = session.timeline.state
        if timeline is None:
            st[S_HAS_NEXT] = 0.0
        else:
            st[S_HAS_NEXT] = 1.0
            st[S_NEXT_T], st[S_LAST_PERIOD] = timeline
        st[S_TICK_HZ] = session.tick_hz
        use_y = session.axis == "y"
        cal = session.calibration.y if use_y else session.calibration.x
        st[S_ZERO_G] = cal.zero_g_duty
        st[S_SENS] = cal.sensitivity_duty_per_g
        st[S_SAT_LIMIT] = SATURATION_FRACTION * session.range_g * STANDARD_GRAVITY_MPS2  # as on_sample
        st[S_VALID_MASK] = _Y_INVALID if use_y else _X_INVALID
        st[S_AXIS_Y] = 1.0 if use_y else 0.0
        link = self.link
        taken = run_chunk(np.frombuffer(data, np.uint8), st, *link.kernel_args, link.kernel_out)
        (n, lost, gaps, invalid, saturated, last_lost, last_saturated, entry) = st[R_SAMPLES:N_SLOTS].tolist()
        n = int(n)
        self.samples = n
        if not n:
            return 0
        decoder.account_samples(taken, n, int(st[S_LAST_SEQ]), int(lost), int(gaps))
        session.timeline.resume(float(st[S_NEXT_T]), float(st[S_LAST_PERIOD]))
        counters = session.counters
        counters.samples += n
        counters.samples_invalid += int(invalid)
        counters.samples_saturated += int(saturated)
        self.last_lost = int(last_lost)
        self.last_saturated = int(last_saturated)
        self.entered_standstill = entry > 0.0
        return taken
