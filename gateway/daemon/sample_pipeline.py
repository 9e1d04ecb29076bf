"""Board bytes in, estimates out: the one path from the serial line to a position.

`SamplePipeline.feed(data)` takes bytes as they come off the board's line, in any
chunking, and returns what they did (`ChunkResult`); `latest()` is the newest estimate.
No I/O and no clock: the daemon, `adxlgw record`, the tests and the benchmarks drive the
same object.

How: a `StreamDecoder` finds the frames and hands them here (this class is its
`SampleSink`). Reports (STATUS/HELLO) come one by one in Python: tick rate, board
temperature, resets. Runs of SAMPLE frames go to `run_samples` (gateway/daemon/sample_loop.py,
with the slots of the state array it shares with this class), one call per run, which
for each frame decodes it (`board_protocol.sample_at`), counts the samples lost before
it (`seq_step`), times it (`conversion.advance_sample_time`), converts its duty cycle
(`conversion.duty_to_mps2`), judges validity and clipping, and steps the estimator
(`estimator_kernel.step`). `run_samples` is compiled by numba when it can be (at 500
samples/s, on a VM that wakes the daemon cold each time, Python per sample was most of
the daemon's CPU: docs/daemon.md); with ADXLGW_NO_JIT=1, or without numba, the very same
function runs as plain Python — one implementation under two runners
(tests/daemon/test_sample_pipeline.py compares them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.board_decoder import DecoderCounters, StreamDecoder
from drivers.board_protocol import (
    FLAG_TIMER_OVERFLOW,
    FLAG_X_TIMED_OUT,
    FLAG_Y_TIMED_OUT,
    FLAGS_RESERVED,
    Hello,
    Status,
)
from gateway.core import estimator_kernel as K
from gateway.core.conversion import Calibration
from gateway.core.estimator import Estimate, RealtimeEstimator
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.jit import JIT_ENABLED
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.daemon.sample_loop import (
    N_SLOTS,
    R_FAULT,
    R_OUTAGE_S,
    R_SAMPLES,
    S_AXIS_Y,
    S_INVALID_MASK,
    S_OUTAGE_TAKEN,
    S_SAT_LIMIT,
    S_SENS,
    S_STOP_BY_HINT,
    S_TEMP_C,
    S_TICK_HZ,
    S_TIMED,
    S_ZERO_G,
    run_samples,
)

# A reading within 2 % of the ±2 g range is treated as clipped (the ADXL202 saturates
# a little beyond 2 g; the nominal duty cycle limits are 25 % and 75 %).
SATURATION_FRACTION = 0.98

_X_INVALID = FLAG_X_TIMED_OUT | FLAG_TIMER_OVERFLOW | FLAGS_RESERVED
_Y_INVALID = FLAG_Y_TIMED_OUT | FLAG_TIMER_OVERFLOW | FLAGS_RESERVED
NO_MODEL_TERMS = np.zeros((0, 3))  # model_compensation.sample_terms of a pipeline without a model


@dataclass(slots=True)
class PipelineCounters:
    samples: int = 0  # estimated (timed) samples
    samples_invalid: int = 0
    samples_saturated: int = 0
    # SAMPLEs that arrived before any STATUS/HELLO told the tick rate: time is unknown
    samples_without_tick_rate: int = 0
    # resets seen as HELLO, plus resets inferred from STATUS uptime going backwards
    resets_announced: int = 0
    resets_inferred: int = 0
    # the estimator's state went non-finite or diverged, and it started over
    estimator_faults: int = 0


@dataclass(slots=True)
class ChunkResult:
    """What one `feed` did."""

    samples: int = 0  # samples estimated
    samples_lost: int = 0  # samples lost on the line before them (seq gaps)
    saturated: int = 0  # clipped samples among them
    invalid: int = 0  # samples whose axis carried no valid measurement
    board_reset: bool = False  # the board restarted (HELLO, or STATUS uptime went back)
    entered_standstill: bool = False
    estimator_fault: bool = False  # the estimator's state broke and it started over
    outage_s: float = 0.0  # > 0: a seq gap this long (board's clock) started the estimator over


@dataclass(frozen=True, slots=True)
class BoardInfo:
    """What the board's reports said last."""

    tick_hz: int | None = None
    temp_c: float | None = None
    uptime_s: int | None = None
    firmware: tuple[int, int] | None = None


class SamplePipeline:
    """Board bytes → decoded, timed, converted samples → the realtime estimator.

    The published position is the estimator's minus a reference offset: `tare()` makes
    here zero (referenced); a board reset or a new axis starts the estimator over and
    keeps the position continuous, but no longer referenced.

    Starting over, the axis may be moving (a daemon restarted mid-move, a board that
    reset mid-cruise): the estimator starts with the velocity unknown, and the position
    is not trustworthy until a stop is seen on evidence (`RealtimeEstimator.restart`).
    Only where the axis is known to stand at the very start (`start_at_rest`: a machine
    homed before the gateway starts, a recording, the emulated board) is the first quiet
    window taken as a rest.
    """

    def __init__(self, calibration: Calibration, settings: EstimatorSettings, axis: str = "x",
                 range_g: float = 2.0, start_position_m: float = 0.0, start_at_rest: bool = False,
                 travel_m: tuple[float, float] | None = None, model_terms: np.ndarray = NO_MODEL_TERMS):
        self.estimator = RealtimeEstimator(settings)
        #: the axis's travel, [lowest, highest] published position (estimator.travel_m):
        #: bounds the published σ (see _build_latest) and how long a cruise can last (the
        #: estimator's quiet stop); None: no bound, the settings' own travel
        self.travel_m = None
        self.set_travel(travel_m)
        self._latest: Estimate | None = None  # latest()'s cache, None: build anew
        if not start_at_rest:
            self.estimator.restart()
        self.hint: bool | None = None  # the machine's word: True at rest, False moving
        self.counters = PipelineCounters()
        self.board = BoardInfo()
        self._decoder = StreamDecoder(sink=self)
        #: What the decoder saw (bytes, frames, CRC errors, samples lost, …): live, read
        #: only (an attribute, not a property: every snapshot reads it)
        self.decoder_counters: DecoderCounters = self._decoder.live_counters
        self._buf: bytes | None = None  # the decoder's buffer and its numpy view (see take_samples)
        self._array: np.ndarray | None = None
        self._st = np.zeros(N_SLOTS)
        self._st[S_TEMP_C] = math.nan
        #: the sensor model's causal terms (model_compensation.sample_terms), applied to
        #: every sample before the estimator sees it
        self.model_terms = np.ascontiguousarray(model_terms, dtype=float).reshape(-1, 3)
        self._range_g = range_g
        self.set_calibration(calibration, axis)
        # published = estimator position − offset; a start position (e.g. the last one
        # published before a restart) is a prior to continue from, not a reference
        self.reference_offset_m = -start_position_m
        #: the variance of that offset, m²: what the position carries from before this
        #: estimator's start (a restored position, an estimate before a start-over), added to
        #: the estimator's own in every published σ (set_start_uncertainty, _start_over)
        self.reference_var_m2 = 0.0
        # the filter's position variance the last time it moved untrusted (its velocity
        # lost), and whether the current stop was accepted without evidence (see
        # _keep_sigma_of_a_stop_on_quiet_alone)
        self._untrusted_motion_var_m2 = 0.0
        self._in_stop_on_quiet = False
        self.referenced = False
        self._estimated = False  # a sample went through the estimator since start or reset
        self._result = ChunkResult()
        self._hellos_seen = 0
        # the first call compiles (numba, seconds; cached on disk after): now, not on the
        # first sample of the board
        probe = RealtimeEstimator(settings)
        # (a read-only array: what np.frombuffer gives take_samples; another type compiles anew)
        run_samples(np.frombuffer(b"", np.uint8) if JIT_ENABLED else b"", 0, -1, np.zeros(N_SLOTS),
                    self.model_terms, probe.params, *probe.state)

    # ---------------------------------------------------------------- input --
    def feed(self, data: bytes | bytearray | memoryview) -> ChunkResult:
        """Bytes from the board's line, in any chunking: every frame they complete goes
        through; what it did comes back."""
        self._result = result = ChunkResult()
        self._latest = None
        self._decoder.feed(data)
        self._latest = None
        return result

    def take_samples(self, buf: bytes, pos: int, last_seq: int) -> tuple[int, int, int, int, int, int, int]:
        """`SampleSink`: a run of SAMPLE frames through `run_samples` (the decoder calls it).
        A run that stops before an outage (a seq gap longer than sample_loop.OUTAGE_S of the
        board's clock) starts the estimator over there and runs on from that frame."""
        if JIT_ENABLED:  # compiled code takes the bytes as a numpy array (no copy), plain Python as they are
            if buf is not self._buf:
                self._buf, self._array = buf, np.frombuffer(buf, np.uint8)
            buf = self._array
        end, taken, last_seq, lost_total, gaps, repeats, backwards = self._run(buf, pos, last_seq)
        while self._st[R_OUTAGE_S] > 0.0:
            self._outage(float(self._st[R_OUTAGE_S]))
            self._st[S_OUTAGE_TAKEN] = 1.0
            end, more, last_seq, more_lost, more_gaps, more_repeats, more_backwards = self._run(buf, end, last_seq)
            taken += more
            lost_total += more_lost
            gaps += more_gaps
            repeats += more_repeats
            backwards += more_backwards
        # plain ints: run as plain Python (no numba), the run's numbers are numpy's
        return int(end), int(taken), int(last_seq), int(lost_total), int(gaps), int(repeats), int(backwards)

    def _run(self, buf, pos: int, last_seq: int) -> tuple[int, int, int, int, int, int, int]:
        """One `run_samples` call and its results taken into the counters and the chunk's result."""
        st = self._st
        ran = run_samples(buf, pos, last_seq, st, self.model_terms, self.estimator.params, *self.estimator.state)
        self._latest = None
        (samples, lost, _gaps, invalid, saturated, no_tick, entry, fault) = st[R_SAMPLES:R_FAULT + 1].tolist()
        c = self.counters
        r = self._result
        samples = int(samples)
        c.samples += samples
        c.samples_invalid += int(invalid)
        c.samples_saturated += int(saturated)
        c.samples_without_tick_rate += int(no_tick)
        r.samples += samples
        r.samples_lost += int(lost)
        r.invalid += int(invalid)
        r.saturated += int(saturated)
        if samples:
            self._estimated = True
        if entry:
            r.entered_standstill = True
        self._keep_sigma_of_a_stop_on_quiet_alone()
        if fault:
            # numbers that mean nothing are not kept: start over, flagged
            c.estimator_faults += 1
            r.estimator_fault = True
            self._start_over()
        return ran

    def _outage(self, length_s: float) -> None:
        """A seq gap of `length_s` on the board's clock: the axis may have moved meanwhile,
        the velocity is no longer known (nothing to do before the first estimate)."""
        self._result.outage_s = max(self._result.outage_s, length_s)
        if self.latest() is not None:
            self._start_over()

    def _keep_sigma_of_a_stop_on_quiet_alone(self) -> None:
        """A stop accepted while the position is untrusted (the velocity was lost — a gap,
        an outage, a restart mid-move — and a quiet stretch outlasted any cruise: estimator
        quiet_stop_s) says the axis stands now, not where it stopped. The stop's velocity
        update corrects the position as if the velocity error had stayed constant since the
        velocity was lost, which an outage or a restart mid-move does not promise (the
        fault benchmark: 0.2–1.3 m off after such a stop with a σ of 35–65 mm). So the
        position keeps the σ it had in motion just before that stop, until a tare.
        (Seen at the end of each run of samples: in the daemon a run is a batch of a few
        samples, so "just before" is within a batch.)"""
        out = self.estimator.state.out
        flags = int(out[K.O_FLAGS])
        if not flags & K.F_STANDSTILL:
            self._in_stop_on_quiet = False
            if flags & K.F_UNTRUSTED:
                self._untrusted_motion_var_m2 = out[K.O_POS_VAR]
            return
        if flags & K.F_UNTRUSTED and not self._in_stop_on_quiet and self._untrusted_motion_var_m2 > 0.0:
            self._in_stop_on_quiet = True
            self.reference_var_m2 += self._untrusted_motion_var_m2
            self._untrusted_motion_var_m2 = 0.0
            self._latest = None

    def on_report(self, frame: Status | Hello) -> None:
        """`SampleSink`: a STATUS or HELLO; a board reset loses time continuity."""
        reset = False
        if isinstance(frame, Hello):
            self._hellos_seen += 1
            if self._hellos_seen > 1 or self.counters.samples:
                self.counters.resets_announced += 1
                reset = True
        elif self.board.uptime_s is not None and frame.uptime_s < self.board.uptime_s:
            # uptime went backwards without a HELLO: the board restarted and its HELLO was lost
            self.counters.resets_inferred += 1
            reset = True
        if reset:
            self._result.board_reset = True
            self._start_over()
        tick_hz = frame.tick_hz if frame.tick_hz > 0 else self.board.tick_hz
        self.board = BoardInfo(tick_hz, frame.temp_c, frame.uptime_s, (frame.fw_major, frame.fw_minor))
        self._st[S_TICK_HZ] = float(tick_hz or 0)
        self._st[S_TEMP_C] = math.nan if frame.temp_c is None else frame.temp_c

    def set_model_terms(self, model_terms: np.ndarray) -> None:
        """The sensor model's causal terms from now on (a reload of calibration.model)."""
        self.model_terms = np.ascontiguousarray(model_terms, dtype=float).reshape(-1, 3)

    # ------------------------------------------------------------- commands --
    def tare(self) -> bool:
        """Position := 0 here (referenced from now on); False when nothing is estimated yet."""
        est = self.latest()
        if est is None:
            return False
        self.reference_offset_m += est.pos_m
        self.reference_var_m2 = 0.0  # here is zero by definition
        self.referenced = True
        self._latest = None
        return True

    def request_bias_reestimate(self) -> bool:
        """Accepted only at standstill: the bias variance widens and the rest re-measures it."""
        est = self.latest()
        if est is None or not est.standstill:
            return False
        self.estimator.request_bias_reestimate()
        self._latest = None
        return True

    def set_start_uncertainty(self, std_m: float) -> None:
        """The start position's own uncertainty (1σ, m): a restored position is a prior whose
        σ says what the axis could have done while nobody watched (state_store.restored_position_std_m)."""
        self.reference_var_m2 = std_m * std_m if math.isfinite(std_m) else math.inf
        self._latest = None

    def set_travel(self, travel_m: tuple[float, float] | None) -> None:
        """The axis's travel from now on (estimator.travel_m, at start and at a reload): it
        bounds the published σ and, in the estimator, how long a cruise can last."""
        self.travel_m = travel_m
        if travel_m is not None:
            self.estimator.set_travel_span(travel_m[1] - travel_m[0])
        self._latest = None

    def reset(self) -> None:
        """Start the estimator over (e.g. continuity lost); the position stays continuous
        but is no longer referenced."""
        self._start_over()

    def set_hint(self, at_rest: bool | None) -> None:
        """The machine's standstill hint from now on: True at rest, False moving, None
        unknown. Evidence, not an order: a rest hint while a window of the accelerometer
        shows motion is flagged (F_HINT_CONFLICT) and not obeyed."""
        self.hint = at_rest
        self.estimator.set_hint(None if at_rest is None else (1.0 if at_rest else 0.0))

    def set_calibration(self, calibration: Calibration, axis: str) -> None:
        """Calibration and axis for the samples from now on; another axis starts over."""
        if axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
        changed = getattr(self, "axis", axis) != axis
        self.calibration = calibration
        self.axis = axis
        cal = calibration.y if axis == "y" else calibration.x
        st = self._st
        st[S_ZERO_G] = cal.zero_g_duty
        st[S_SENS] = cal.sensitivity_duty_per_g
        st[S_SAT_LIMIT] = SATURATION_FRACTION * self._range_g * STANDARD_GRAVITY_MPS2
        st[S_INVALID_MASK] = _Y_INVALID if axis == "y" else _X_INVALID
        st[S_AXIS_Y] = 1.0 if axis == "y" else 0.0
        if changed:
            self._start_over()

    def _start_over(self) -> None:
        est = self.latest()
        if est is not None and math.isfinite(est.pos_m):
            # keep the published position continuous; it is just no longer trusted, and no
            # more certain than it was (the new estimator starts with a position variance 0)
            self.reference_offset_m = -est.pos_m
            if math.isfinite(est.pos_std_m):
                self.reference_var_m2 = est.pos_std_m * est.pos_std_m
        self.referenced = False
        self.estimator.restart()  # the axis may be moving: the velocity is not known
        self.set_hint(self.hint)  # the machine's word still holds
        self._estimated = False
        self._latest = None
        self._untrusted_motion_var_m2 = 0.0
        self._in_stop_on_quiet = False
        self._st[S_TIMED] = 0.0
        self._st[S_STOP_BY_HINT] = 0.0

    # --------------------------------------------------------------- output --
    def latest(self) -> Estimate | None:
        """The newest estimate, position from the reference; None before any sample
        since the start or the last start-over. Built once per change (every wire's
        snapshot and status bits read it)."""
        if self._latest is None:
            self._latest = self._build_latest()
        return self._latest

    def _build_latest(self) -> Estimate | None:
        if not self._estimated:
            return None
        state = self.estimator.state
        # the kernel's output as one list (each numpy access is a call, and this runs for
        # every snapshot that follows a change, cold on a VM), with the published σ put in
        # it so that the estimate is built once: a dataclasses.replace after it cost more
        # than the build itself; the kernel's own array is left as it is
        out = state.out.tolist()
        out[K.O_POS_VAR] = self._published_pos_var_m2(out[K.O_POS] - self.reference_offset_m, out[K.O_POS_VAR])
        return Estimate.from_kernel_values(state.misc.item(K.M_T_PREV), out, self.reference_offset_m,
                                           held_std_unknown=True)

    def _published_pos_var_m2(self, pos_m: float, filter_var_m2: float) -> float:
        """The variance of the published position: the filter's, plus the start position's
        own (reference_var_m2: independent of the filter's), bounded by the travel. A
        variance the filter does not have (negative, NaN) stays as it is: σ unknown."""
        if not filter_var_m2 >= 0.0:
            return filter_var_m2
        var_m2 = filter_var_m2 + self.reference_var_m2
        if self.travel_m is not None:
            # The axis is somewhere in its travel: the published position is never farther
            # from the truth than from the farther end of the travel, whatever the filter's
            # σ says (after a board reset or an outage it grows without bound: metres in
            # seconds with the velocity unknown). That distance as σ keeps every position
            # the axis can have within 1σ; an estimate outside the travel gets a σ that
            # reaches back over all of it.
            lo, hi = self.travel_m
            farthest_m = max(pos_m - lo, hi - pos_m)
            if var_m2 > farthest_m * farthest_m:
                var_m2 = farthest_m * farthest_m
        return var_m2

    @property
    def stop_by_hint(self) -> bool:
        """The current standstill was accepted on the machine's hint."""
        return self._st[S_STOP_BY_HINT] > 0.0

    @property
    def last_seq(self) -> int:
        return self._decoder.last_seq
