"""The ADXL202's two duty-cycle outputs as pin waveforms, from the simulator's counts.

Each sensor period k starts with XOUT and YOUT going high together (the part starts
both duty cycles at once) and each falls after its high time: XOUT at
``start_s[k] + t1x[k]/tick_hz``, YOUT likewise. The simulator's counts are the truth a
board's timer should measure; the waveform is that truth as edges in time, for a
cycle-accurate simulation of the board (scripts/board-in-ucsim) to time again.

A stuck input (for the firmware's timeout) holds one pin at one level for a while: its
edges inside the stretch are dropped.

Pure numbers and text; the files and processes are in drivers/ucsim_board.py.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

AXES = ("x", "y")
# s51's outside value of port 3's pins; INT0 = P3.2 and INT1 = P3.3 gate Timers 0 and 1
VCD_PIN_NAMES = {"x": "pin3.2", "y": "pin3.3"}
VCD_IDS = {"x": "!", "y": '"'}
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class StuckInput:
    """One input held at `level` (0 or 1) from `start_s` for `duration_s` of waveform time."""

    axis: str
    start_s: float
    duration_s: float
    level: int

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise ValueError(f"axis must be one of {', '.join(AXES)}")
        if self.level not in (0, 1):
            raise ValueError("level must be 0 or 1")
        if not (self.start_s >= 0 and self.duration_s > 0):
            raise ValueError("a stuck stretch needs a start ≥ 0 and a positive duration")

    def covers(self, t_s: np.ndarray) -> np.ndarray:
        return (t_s >= self.start_s) & (t_s < self.start_s + self.duration_s)


@dataclass(frozen=True)
class DutyWaveform:
    """Per period: start (both rise), the two falls (s), and the truth in timer ticks."""

    tick_hz: float
    start_s: np.ndarray
    x_fall_s: np.ndarray
    y_fall_s: np.ndarray
    t1x_ticks: np.ndarray
    t1y_ticks: np.ndarray
    t2_ticks: np.ndarray  # start to next start

    def __len__(self) -> int:
        return int(self.start_s.size)

    @property
    def end_s(self) -> float:
        return float(self.start_s[-1] + self.t2_ticks[-1] / self.tick_hz)


def waveform_from_counts(
    tick_hz: float, t1x: np.ndarray, t1y: np.ndarray, t2: np.ndarray, lead_s: float = 0.0
) -> DutyWaveform:
    """The waveform whose periods are the counts given (a simulated run's t1x, t1y, t2),
    the first period starting at `lead_s`. Period k starts where the T2 before it end, so
    a board timing the edges exactly reads the counts back."""
    t2 = np.asarray(t2, dtype=np.float64)
    if np.any(t2 <= 0):
        raise ValueError("every period must be positive")
    t1x = np.asarray(t1x, dtype=np.float64)
    t1y = np.asarray(t1y, dtype=np.float64)
    if np.any(t1x >= t2) or np.any(t1y >= t2) or np.any(t1x <= 0) or np.any(t1y <= 0):
        raise ValueError("a high time must lie inside its period")
    start_s = lead_s + np.concatenate(([0.0], np.cumsum(t2)[:-1])) / tick_hz
    return DutyWaveform(tick_hz, start_s, start_s + t1x / tick_hz, start_s + t1y / tick_hz, t1x, t1y, t2)


def pin_events(wave: DutyWaveform, stuck: tuple[StuckInput, ...] = ()) -> Iterator[tuple[int, dict[str, int]]]:
    """(time in ns, {axis: new level}) in time order, the stuck stretches applied: an edge
    inside a stretch is dropped; the pin goes to the stuck level where it starts and
    back to the waveform's level where it ends."""
    times: list[np.ndarray] = []
    axes: list[np.ndarray] = []
    levels: list[np.ndarray] = []
    for code, axis in enumerate(AXES):
        fall_s = wave.x_fall_s if axis == "x" else wave.y_fall_s
        t = np.concatenate((wave.start_s, fall_s))
        level = np.concatenate((np.ones(len(wave), np.int8), np.zeros(len(wave), np.int8)))
        for s in stuck:
            if s.axis != axis:
                continue
            keep = ~s.covers(t)
            end_s = s.start_s + s.duration_s
            # the waveform's level at the stretch's end: that of its last edge before the
            # end, the edges inside the stretch included (the waveform went on meanwhile)
            before_end = t < end_s
            last = np.argmax(np.where(before_end, t, -np.inf)) if np.any(before_end) else None
            level_at_end = int(level[last]) if last is not None else 0
            t = np.concatenate((t[keep], [s.start_s, end_s]))
            level = np.concatenate((level[keep], [s.level, level_at_end]))
        times.append(t)
        axes.append(np.full(t.size, code, np.int8))
        levels.append(level)
    t_all = np.concatenate(times)
    ns = np.rint(t_all * NS_PER_S).astype(np.int64)
    axis_all = np.concatenate(axes)
    level_all = np.concatenate(levels)
    order = np.lexsort((axis_all, ns))
    current: dict[str, int] = {}
    last_ns = None
    for i in order:
        if last_ns is not None and ns[i] != last_ns and current:
            yield int(last_ns), current
            current = {}
        last_ns = ns[i]
        current[AXES[axis_all[i]]] = int(level_all[i])
    if current:
        yield int(last_ns), current


def vcd_lines(wave: DutyWaveform, stuck: tuple[StuckInput, ...] = ()) -> Iterator[str]:
    """The waveform as a value change dump that s51 replays onto port 3's pins (its VCD
    input: variable names are s51's, time in ns from the replay's start)."""
    yield "$timescale 1ns $end"
    yield "$scope module adxl202 $end"
    for axis in AXES:
        yield f"$var wire 1 {VCD_IDS[axis]} {VCD_PIN_NAMES[axis]} $end"
    yield "$upscope $end"
    yield "$enddefinitions $end"
    yield "$dumpvars"
    for axis in AXES:
        yield f"0{VCD_IDS[axis]}"
    yield "$end"
    for t_ns, changes in pin_events(wave, stuck):
        yield f"#{t_ns}"
        for axis, level in changes.items():
            yield f"{level}{VCD_IDS[axis]}"
