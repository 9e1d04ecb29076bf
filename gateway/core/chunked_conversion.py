"""Board counts to SI units chunk by chunk, with what carries over between chunks.

`recording.to_acceleration` (one chunk: the whole file) and the streamed offline commands
(many chunks) both go through `RawChunkConverter`, so a file gives the same numbers
whichever way it is read. The carry is what the vectorised functions of `conversion`
need from before a chunk: the previous seq, the last usable period count and the
running sample time.

Sequence numbers are untrusted input. A step of the board's 16-bit counter is read as:
    +1                  in order (65535 → 0 is a wrap)
     0                  a repeat
    +2 … +32767         a gap: step − 1 samples lost on the line (their time still passes)
    +32768 … +65535     backwards by 65536 − step: not a loss (a loss that large and a
                        counter running back cannot be told apart; half the counter is
                        where the reading flips). Counted, not integrated as lost time.
Repeats and backward steps are counted and reported; treating them as 65535 lost samples
each was what made `diagnose` build a 15 GB grid from a 247 KB file.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.conversion import Calibration, SampleClock, acceleration_mps2, axis_valid
from gateway.core.units import SEQ_MODULUS, STANDARD_GRAVITY_MPS2

# the largest forward step of seq still read as a gap (see the module docstring)
MAX_GAP_STEP = SEQ_MODULUS // 2 - 1
# more lost samples than this per received one (plus one counter's worth) is not one
# board's continuous sequence; the time axis built on it would be meaningless and the
# diagnosis's full sample grid as large as the losses
MAX_LOST_PER_RECEIVED = 10
# acceleration beyond this multiple of the sensor's range is physically impossible for it:
# the ADXL202 saturates just beyond ±2 g; 1.5× leaves room for the part's sensitivity
# spread (the data sheet's 10–15 %/g read with the nominal 12.5 %/g)
IMPOSSIBLE_RANGE_FACTOR = 1.5


@dataclass
class SequenceReport:
    """What the seq column says about the line, summed over chunks."""

    received: int = 0
    wraps: int = 0
    repeats: int = 0
    backwards: int = 0
    gaps: int = 0
    lost: int = 0
    first_repeat_row: int = -1  # 0-based sample index, −1 when none
    first_backward_row: int = -1

    def problems(self) -> list[str]:
        """One sentence per kind of irregularity (empty when the counter behaved)."""
        out = []
        if self.repeats:
            out.append(f"seq repeats the previous value {self.repeats} times (first at sample "
                       f"{self.first_repeat_row + 1}): not counted as lost samples")
        if self.backwards:
            out.append(f"seq steps backwards {self.backwards} times (first at sample "
                       f"{self.first_backward_row + 1}): not counted as lost samples")
        return out


def classify_seq_steps(seq: np.ndarray, previous: int | None, first_index: int, report: SequenceReport):
    """Samples lost before each one, by the rules in the module docstring; updates report."""
    seq = np.asarray(seq, dtype=np.int64)
    lost = np.zeros(seq.shape, dtype=np.int64)
    if seq.size == 0:
        return lost
    before = np.empty_like(seq)
    before[1:] = seq[:-1]
    has_prev = np.ones(seq.shape, dtype=bool)
    if previous is None:
        has_prev[0] = False
        before[0] = seq[0] - 1
    else:
        before[0] = previous
    step = (seq - before) % SEQ_MODULUS
    gap = has_prev & (step >= 2) & (step <= MAX_GAP_STEP)
    repeat = has_prev & (step == 0)
    back = has_prev & (step > MAX_GAP_STEP)
    lost[gap] = step[gap] - 1
    report.received += int(seq.size)
    report.wraps += int(np.count_nonzero(has_prev & (step == 1) & (seq == 0)))
    report.gaps += int(np.count_nonzero(gap))
    report.lost += int(lost.sum())
    n_rep, n_back = int(np.count_nonzero(repeat)), int(np.count_nonzero(back))
    if n_rep and report.first_repeat_row < 0:
        report.first_repeat_row = first_index + int(np.argmax(repeat))
    if n_back and report.first_backward_row < 0:
        report.first_backward_row = first_index + int(np.argmax(back))
    report.repeats += n_rep
    report.backwards += n_back
    return lost


@dataclass
class RawChunk:
    """One chunk in SI units: per sample time, both axes (NaN where invalid), validity."""

    t_s: np.ndarray
    acc_mps2: dict[str, np.ndarray]
    valid: dict[str, np.ndarray]
    lost_before: np.ndarray
    impossible: dict[str, int]  # per axis: samples the board passed that lie beyond the possible range


class RawChunkConverter:
    """Raw-form columns (seq, t1x, t1y, t2, flags) → sample times and acceleration."""

    def __init__(self, tick_hz: float, calibration: Calibration, range_g: float):
        self.tick_hz = float(tick_hz)
        self.calibration = calibration
        self.limit_mps2 = IMPOSSIBLE_RANGE_FACTOR * range_g * STANDARD_GRAVITY_MPS2
        self.report = SequenceReport()
        self._prev_seq: int | None = None
        self._clock = SampleClock(tick_hz)  # the one timing rule, carried from chunk to chunk
        self._any_period = False

    def convert(self, seq, t1x, t1y, t2, flags) -> RawChunk:
        """The next chunk. Raises ValueError when no period count is usable yet."""
        t2 = np.asarray(t2, dtype=float)
        start = self.report.received
        lost = classify_seq_steps(seq, self._prev_seq, start, self.report)
        if self.report.lost > MAX_LOST_PER_RECEIVED * self.report.received + SEQ_MODULUS:
            raise ValueError(
                f"seq says {self.report.lost} samples were lost for {self.report.received} received "
                f"(by sample {self.report.received}): more than {MAX_LOST_PER_RECEIVED} per received "
                "sample is not one board's continuous sequence")
        good = t2 > 0
        if not self._any_period and not good.any():
            raise ValueError("no sample has a usable period count (t2 > 0)")
        self._any_period = True
        t_s = self._clock.times(t2, lost)
        flags = np.asarray(flags, dtype=np.int64)
        acc, valid, impossible = {}, {}, {}
        for ax in ("x", "y"):
            t1 = np.asarray(t1x if ax == "x" else t1y, dtype=float)
            a = acceleration_mps2(t1, t2, getattr(self.calibration, ax))
            board_ok = axis_valid(flags, t1, t2, ax) & np.isfinite(a)
            ok = board_ok & (np.abs(a) <= self.limit_mps2)
            impossible[ax] = int(np.count_nonzero(board_ok & ~ok))
            valid[ax] = ok
            acc[ax] = np.where(ok, a, np.nan)
        self._prev_seq = int(np.asarray(seq)[-1]) if len(seq) else self._prev_seq
        return RawChunk(t_s, acc, valid, lost, impossible)
