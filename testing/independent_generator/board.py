"""The ADXL202 on the 8051 board, from the data sheet and board facts in /work/shared/spec.

Built on a fine time grid (FINE_HZ), in this order:

1. the acceleration at the element (motion, plus what hidden effects add or change), in g;
2. its noise: white, 200 µg/√Hz (data sheet noise floor) at the fine rate;
3. the output filter: the internal 32 kΩ with this part's CX (0.1 µF nominal, ±10 %
   capacitor tolerance: f−3dB = 1/(2π·32 kΩ·CX) ≈ 49.7 Hz), discretised with the bilinear
   (Tustin) transform — not the exact one-pole step response;
4. the duty-cycle modulator: each cycle of length T2 (RSET/125 MΩ, RSET within 1 %,
   a 20 ppm wobble per cycle) goes high at its start and low when the duty
   D0 + S·y reached at that moment has passed (D0, S per part: offset within ±0.4 %
   duty, sensitivity within 1 %) — the reading is the filtered value at the falling
   edge, not a period mean;
5. the 8051 counts ticks of its 921 600 Hz timer (random phase) while each duty output is
   high (Timers 0 and 1 gated by INT0/INT1): T1 is a difference of floored edge counts.
   Timer 2 makes the baud rate (spec correction of 2026-11-27), so T2 is timed only on
   every T2_EVERY-th period and each frame carries the latest value;
6. each SAMPLE frame leaves when its period ends, 15 bytes at 115 200 baud; the board's
   USB side is a full-speed device polled once per 1 ms frame, the host reads it 4 ms
   later with 0.3 ms (1σ) jitter, one reader thread, in order.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import bilinear, lfilter

FINE_HZ = 20_000.0
TICK_HZ = 921_600.0
T2_NOMINAL_S = 250e3 / 125e6  # RSET = 250 kΩ
NOISE_G_PER_RTHZ = 200e-6
R_FILTER_OHM = 32e3
CX_NOMINAL_F = 0.1e-6
UART_FRAME_S = 15 * 10 / 115_200
HOST_LATENCY_S = 4e-3
HOST_JITTER_S = 0.3e-3
USB_FRAME_S = 1e-3  # full-speed USB: the host polls the device once per 1 ms frame
T2_EVERY = 16  # the board times T2 on one period in 16 (its third timer makes the baud rate)
G = 9.80665


def rc_lowpass(x: np.ndarray, cutoff_hz: float, fs: float) -> np.ndarray:
    """1/(1 + s/ωc) by the bilinear transform, started settled at x[0]."""
    w = 2.0 * math.pi * cutoff_hz
    b, a = bilinear([w], [1.0, w], fs)
    zi = x[0] * (b[1] - a[1]) if a.size > 1 else 0.0  # steady state of the transposed form
    y, _ = lfilter(b, a, x, zi=[zi])
    return y


@dataclass
class Part:
    """One ADXL202 and board as built: the values a data sheet leaves open."""

    d0_x: float
    d0_y: float
    s_x: float
    s_y: float
    cx_f: float
    t2_s: float
    tick_phase: float

    @staticmethod
    def draw(rng: np.random.Generator) -> Part:
        return Part(
            d0_x=0.5 + rng.uniform(-0.004, 0.004), d0_y=0.5 + rng.uniform(-0.004, 0.004),
            s_x=0.125 * (1 + rng.uniform(-0.01, 0.01)), s_y=0.125 * (1 + rng.uniform(-0.01, 0.01)),
            cx_f=CX_NOMINAL_F * (1 + rng.uniform(-0.10, 0.10)),
            t2_s=T2_NOMINAL_S * (1 + rng.uniform(-0.01, 0.01)),
            tick_phase=float(rng.uniform(0.0, 1.0)),
        )

    @property
    def bandwidth_hz(self) -> float:
        return 1.0 / (2.0 * math.pi * R_FILTER_OHM * self.cx_f)


@dataclass
class Frames:
    """What the board sent and the host saw, one row per sample frame."""

    seq: np.ndarray
    t1x: np.ndarray
    t1y: np.ndarray
    t2: np.ndarray
    t_host_s: np.ndarray
    start_s: np.ndarray  # true start of each period (the reference is evaluated here)
    extra: dict = field(default_factory=dict)


def periods(part: Part, duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Rising-edge times: T2 with a 20 ppm wobble per cycle."""
    n = int(duration_s / part.t2_s) + 2
    t2 = part.t2_s * (1.0 + 20e-6 * rng.standard_normal(n))
    return np.concatenate([[0.0], np.cumsum(t2)])


def element_noise(n: int, rng: np.random.Generator) -> np.ndarray:
    """White noise of density NOISE_G_PER_RTHZ sampled at FINE_HZ (g)."""
    return NOISE_G_PER_RTHZ * math.sqrt(FINE_HZ / 2.0) * rng.standard_normal(n)


def duty_cycles(t_fine: np.ndarray, y_g: np.ndarray, rise_s: np.ndarray, d0: float, s: float,
                clip_g: float = 2.0) -> np.ndarray:
    """Falling-edge times: the first moment in each cycle where the elapsed fraction
    reaches the duty D0 + S·y (y clipped at the output stage's limit)."""
    t2 = np.diff(rise_s)
    # first guess at the nominal half-period, then one fixed-point step on y at the edge
    fall = rise_s[:-1] + d0 * t2
    for _ in range(2):
        y = np.interp(fall, t_fine, y_g)
        duty = np.clip(d0 + s * np.clip(y, -clip_g, clip_g), 0.02, 0.98)
        fall = rise_s[:-1] + duty * t2
    return fall


def capture(rise_s: np.ndarray, fall_x: np.ndarray, fall_y: np.ndarray, phase: float):
    """The 8051's counts: differences of floored edge times on the free-running counter."""
    def count(t):
        return np.floor(t * TICK_HZ + phase).astype(np.int64)

    r = count(rise_s)
    timed = np.diff(r)
    # each frame carries the latest period the board has timed (one in T2_EVERY)
    latest = (np.arange(timed.size) // T2_EVERY) * T2_EVERY
    t2 = timed[latest]
    t1x = count(fall_x) - r[:-1]
    t1y = count(fall_y) - r[:-1]
    return t1x, t1y, t2


def host_arrivals(end_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Arrival times of an ordinary link: the frame's end + UART, at the next 1 ms USB
    poll, + 4 ms ± 0.3 ms, stamped in order by one reader thread."""
    t = end_s + UART_FRAME_S
    phase = rng.uniform(0, USB_FRAME_S)
    t = np.ceil((t - phase) / USB_FRAME_S) * USB_FRAME_S + phase
    t = t + HOST_LATENCY_S + HOST_JITTER_S * rng.standard_normal(t.size)
    return np.maximum.accumulate(t)
