"""The compiled per-sample loop of `SamplePipeline` and the state slots it shares with it.

`run_samples` takes a run of SAMPLE frames through decoding, continuity, timing,
conversion, the sensor model's correction and one estimator step each; the board-side
state and the run's results travel in one float64 array whose slots are named here
(`S_*`: state kept between runs, `R_*`: results of one run). They live apart from
`SamplePipeline` (gateway/daemon/sample_pipeline.py, the only caller) because this is the
code numba compiles: plain functions over arrays and module constants, no objects.
"""
from __future__ import annotations

import math

from drivers.board_protocol import (
    FLAG_TIMER_OVERFLOW,
    FLAG_X_TIMED_OUT,
    FLAG_Y_TIMED_OUT,
    SAMPLE_FRAME_LENGTH,
    SEQ_BACKWARDS,
    SEQ_REPEAT,
    sample_at,
    seq_step,
)
from gateway.core import estimator_kernel as K
from gateway.core.conversion import advance_sample_time, duty_to_mps2
from gateway.core.jit import jit
from gateway.core.model_compensation import term_correction

# ---- the float64 array that carries the board-side state in and the results out -----
S_TIMED = 0  # 1 once a sample was timed since the start or the last board reset
S_NEXT_T = 1  # time of the next sample (s)
S_LAST_PERIOD = 2  # last period (s)
S_TICK_HZ = 3  # board timer rate; 0: not known yet (no STATUS/HELLO seen)
S_ZERO_G = 4  # calibration of the configured axis: zero-g duty cycle …
S_SENS = 5  # … and sensitivity (duty per g)
S_SAT_LIMIT = 6  # |acceleration| at or above this is clipped (m/s²)
S_INVALID_MASK = 7  # flags that make the configured axis' counts invalid
S_AXIS_Y = 8  # 1: the configured axis is y
S_STOP_BY_HINT = 9  # 1: the current standstill was accepted on the machine's hint
R_SAMPLES = 10  # results of one run: samples estimated …
R_LOST = 11  # … samples lost before them (seq gaps) …
R_GAPS = 12  # … in how many gaps
R_INVALID = 13
R_SATURATED = 14
R_NO_TICK = 15  # SAMPLEs before any tick rate: time unknown, not estimated
R_ENTRY = 16  # 1: some step began a standstill
R_FAULT = 17  # 1: some step left the estimator's state not finite or diverged
S_TEMP_C = 18  # the board's temperature from its latest report (°C); NaN: none yet
R_OUTAGE_S = 19  # > 0: the run stopped before a seq gap this long on the board's clock (s)
S_OUTAGE_TAKEN = 20  # 1: the caller started over for that gap; the next frame runs on
N_SLOTS = 21

# A seq gap longer than this on the board's own clock is an outage: the estimator starts
# over with the velocity unknown rather than bridge it (benchmarks/daemon/fault_benchmark.py:
# a 2 s outage bridged came back 2 m off with a 75 mm σ; gaps of a few samples cost < 1 mm
# there). Judged on the board's seq and period, not on when bytes reached the host: a
# host that fell behind and reads a backlog at once lost nothing.
OUTAGE_S = 0.25

_CLIPPED_FLAGS = FLAG_X_TIMED_OUT | FLAG_Y_TIMED_OUT | FLAG_TIMER_OVERFLOW
_FRAME = SAMPLE_FRAME_LENGTH
_F_ENTRY = K.F_ENTRY
_F_FAULT = K.F_FAULT
_F_HINT_REST = K.F_HINT_REST
_F_STANDSTILL = K.F_STANDSTILL
_O_FLAGS = K.O_FLAGS
_compiled_sample_at = jit(sample_at)
_compiled_seq_step = jit(seq_step)
_compiled_term_correction = jit(term_correction)


@jit
def corrected_sample(acc, terms, moving, temp_c):
    """One sample less the sensor model's causal terms, in the file's order
    (model_compensation.term_correction: the formula offline corrections use too)."""
    for i in range(terms.shape[0]):
        temp_dev_c = temp_c - terms[i, 2] if math.isfinite(temp_c) else 0.0
        acc = _compiled_term_correction(terms[i, 0], terms[i, 1], acc, moving, temp_dev_c)
    return acc


@jit
def run_samples(buf, pos, last_seq, st, terms, prm, x, P, misc, ring_z, ring_ok, snap, gain, out):
    """The run of whole, CRC-valid SAMPLE frames from `buf[pos]` on, each through
    decoding, continuity, timing, conversion, the sensor model's correction (`terms`:
    model_compensation.sample_terms; the motion flag is the filter's standstill verdict
    of the sample before, the temperature the board's latest report) and one estimator
    step.

    The estimator's `KernelState` comes as its eight arrays (`*state`, in its field
    order) and is put together here: numba's dispatcher types plain arrays in C from a
    cache, a named tuple of them more slowly, and this call is made at every wakeup.

    Returns (end, samples, last_seq, lost, gaps, repeats, backwards) as
    `SampleSink.take_samples`; the
    timeline in `st` moves on, the run's results are in its R_* slots. A seq gap longer
    than OUTAGE_S of the board's clock ends the run before its frame (R_OUTAGE_S says how
    long): the caller starts the estimator over, sets S_OUTAGE_TAKEN and runs again
    from `end`, where the gap is counted as any other.
    """
    kstate = K.KernelState(x, P, misc, ring_z, ring_ok, snap, gain, out)
    timed = st[S_TIMED] > 0.0
    next_t = st[S_NEXT_T]
    last_period = st[S_LAST_PERIOD]
    tick_hz = st[S_TICK_HZ]
    zero_g = st[S_ZERO_G]
    sens = st[S_SENS]
    sat_limit = st[S_SAT_LIMIT]
    invalid_mask = int(st[S_INVALID_MASK])
    use_y = st[S_AXIS_Y] > 0.0
    stop_by_hint = st[S_STOP_BY_HINT] > 0.0
    outage_taken = st[S_OUTAGE_TAKEN] > 0.0
    st[R_OUTAGE_S] = 0.0
    temp_c = st[S_TEMP_C]
    n = 0
    lost_total = 0
    gaps = 0
    repeats = 0
    backwards = 0
    invalid = 0
    saturated_n = 0
    no_tick = 0
    entry = False
    fault = False
    while True:
        seq, t1x, t1y, t2, flags = _compiled_sample_at(buf, pos)
        if seq < 0:
            break
        lost, verdict = _compiled_seq_step(last_seq, seq)
        if lost and timed and not outage_taken and lost * last_period > OUTAGE_S:
            st[R_OUTAGE_S] = lost * last_period
            break  # before this frame: the caller starts over, then runs on from it
        outage_taken = False
        pos += _FRAME
        n += 1
        if lost:
            lost_total += lost
            gaps += 1
        elif verdict == SEQ_REPEAT:
            repeats += 1
        elif verdict == SEQ_BACKWARDS:
            backwards += 1
        last_seq = seq
        if tick_hz <= 0.0:  # no STATUS/HELLO yet: the sample's time cannot be told
            no_tick += 1
            continue
        t_s, next_t, last_period = advance_sample_time(timed, next_t, last_period, t2, tick_hz, lost)
        timed = True
        t1 = t1y if use_y else t1x
        acc = math.nan
        if (flags & invalid_mask) == 0 and t2 > 0 and 0 <= t1 <= t2:
            acc = duty_to_mps2(t1 / t2, zero_g, sens)
        ok = math.isfinite(acc)
        if not ok:
            invalid += 1
        elif (flags & _CLIPPED_FLAGS) != 0 or abs(acc) >= sat_limit:
            saturated_n += 1
        if ok and terms.shape[0] > 0:  # clipping is judged on the raw reading, above
            moving = 0.0 if int(kstate.out[_O_FLAGS]) & _F_STANDSTILL else 1.0
            acc = corrected_sample(acc, terms, moving, temp_c)
        K.step(kstate, prm, t_s, acc if ok else 0.0, ok, lost)
        step_flags = int(kstate.out[_O_FLAGS])
        if step_flags & _F_ENTRY:
            entry = True
        if step_flags & _F_FAULT:
            fault = True
        if step_flags & _F_HINT_REST:
            stop_by_hint = True
        elif not step_flags & _F_STANDSTILL:
            stop_by_hint = False
    st[S_TIMED] = 1.0 if timed else 0.0
    st[S_NEXT_T] = next_t
    st[S_LAST_PERIOD] = last_period
    st[S_STOP_BY_HINT] = 1.0 if stop_by_hint else 0.0
    st[R_SAMPLES] = n - no_tick
    st[R_LOST] = lost_total
    st[R_GAPS] = gaps
    st[R_INVALID] = invalid
    st[R_SATURATED] = saturated_n
    st[R_NO_TICK] = no_tick
    st[R_ENTRY] = 1.0 if entry else 0.0
    st[R_FAULT] = 1.0 if fault else 0.0
    st[S_OUTAGE_TAKEN] = 1.0 if outage_taken else 0.0
    return pos, n, last_seq, lost_total, gaps, repeats, backwards
