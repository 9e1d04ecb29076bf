"""The paper's experiment in numbers: motion → ADXL202 → 8051 timer counts → host.

Pipeline, per axis (values in g until the duty cycle):
    truth (motion profile)
    → sensor low-pass (CX/CY, one pole, continuous time), mean over each period
                                                → + white noise (same filter)
    → + zero-g offset + exponential zero drift → extra error terms (hook)
    → sensitivity → clipping at ±range         → duty cycle
    → 8051 timer: edges counted in ticks (T1 and T2 quantised)

Everything is seeded; nothing here does I/O.  An extra error term is one small class:
subclass ``ErrorTerm`` and override ``acceleration_g`` (before clipping and
quantisation) and/or ``samples`` (after: loss, host timing).
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from gateway.core.drift_model import drift_g
from gateway.core.motion_profiles import PiecewiseConstantAcceleration
from gateway.core.sensor_model import BOARD_HOST_LINK, BOARD_SENSOR, HostLinkParams, SensorParams
from gateway.core.units import SEQ_MODULUS, STANDARD_GRAVITY_MPS2


@dataclass
class SignalContext:
    """What an error term may look at while the signal is made."""

    t_s: np.ndarray
    ref_pos_m: np.ndarray
    ref_vel_mps: np.ndarray
    ref_acc_mps2: np.ndarray
    temp_c: np.ndarray
    sensor: SensorParams
    seed: int
    # the motion as the sensing element feels it (CX filter, period mean), g, X axis: set
    # before the error terms run, for terms that act on the motion only (mount, filters)
    motion_x_g: np.ndarray | None = None
    # the motion itself, for terms that evaluate it at other times (a late reference log)
    profile: PiecewiseConstantAcceleration | None = None

    def rng(self, name: str) -> np.random.Generator:
        """An independent, reproducible stream per name: adding a term leaves the others' draws alone."""
        return np.random.default_rng([self.seed, zlib.crc32(name.encode())])


@dataclass
class SimulatedRun:
    """Board counts of a run plus the truth. Arrays are one entry per sample sent."""

    tick_hz: float
    seq: np.ndarray
    t1x: np.ndarray
    t1y: np.ndarray
    t2: np.ndarray
    flags: np.ndarray
    t_s: np.ndarray  # true start time of each sample's period
    t_host_s: np.ndarray  # host arrival time
    temp_c: np.ndarray
    ref_pos_m: np.ndarray
    ref_vel_mps: np.ndarray
    ref_acc_mps2: np.ndarray

    def __len__(self) -> int:
        return int(self.seq.size)

    def select(self, keep: np.ndarray) -> SimulatedRun:
        """The run with only the samples where keep is true (seq keeps its gaps)."""
        return replace(self, **{k: v[keep] for k, v in self.__dict__.items() if isinstance(v, np.ndarray)})

    def recording_columns(self) -> dict[str, np.ndarray]:
        """Columns of the raw recording form, with the truth."""
        return {
            "seq": self.seq,
            "t1x": self.t1x,
            "t1y": self.t1y,
            "t2": self.t2,
            "flags": self.flags,
            "t_host_s": self.t_host_s,
            "temp_c": self.temp_c,
            "ref_pos_m": self.ref_pos_m,
            "ref_vel_mps": self.ref_vel_mps,
            "ref_acc_mps2": self.ref_acc_mps2,
        }


class ErrorTerm:
    """An effect the baseline sensor model lacks. Override one or both hooks."""

    name = "error_term"

    def acceleration_g(self, ctx: SignalContext, acc_x_g: np.ndarray, acc_y_g: np.ndarray):
        return acc_x_g, acc_y_g

    def samples(self, ctx: SignalContext, run: SimulatedRun) -> SimulatedRun:
        return run


def period_mean_lowpass(
    profile: PiecewiseConstantAcceleration, n: int, period_s: float, bandwidth_hz: float
) -> np.ndarray:
    """Mean over each period [k·Ts, (k+1)·Ts] of the true acceleration after the CX/CY filter.

    The filter acts in continuous time, before the duty-cycle modulator, and a duty cycle
    measures the whole period; so each sample is the period's mean of the filtered
    signal. Sampling the unfiltered steps at the period start instead moves every step
    to the next sample: a motion's integral is then wrong by up to a·Ts per step
    (20 mm/s at 10 m/s², mm of position per stroke) for any estimator.

    Exact for piecewise-constant u: y' = (u − y)/τ gives ∫y = ∫u − τ·Δy per period, and
    y at the period edges follows y(k+1) = e^(−Ts/τ)·y(k) + the period's share of each step.
    """
    tau_s = 1.0 / (2.0 * np.pi * bandwidth_hz)
    durations = np.array([s.duration_s for s in profile.segments])
    acc = np.array([s.acc_mps2 for s in profile.segments])
    seg_start = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    vel_start = np.concatenate([[0.0], np.cumsum(acc * durations)[:-1]])
    edges_s = np.arange(n + 1) * period_s
    seg = np.maximum(np.searchsorted(seg_start, edges_s, side="right") - 1, 0)
    # ∫0^t u: the last segment extends past the profile's end, like evaluate() holds it
    u_integral = vel_start[seg] + acc[seg] * (edges_s - seg_start[seg])
    a = np.exp(-period_s / tau_s)
    forcing = acc[seg[:-1]] * (1.0 - a)
    for j in range(1, acc.size):  # steps inside a period: their exact share
        k = int(np.searchsorted(edges_s, seg_start[j], side="right")) - 1
        if 0 <= k < n and seg_start[j] > edges_s[k]:
            forcing[k] += (acc[j] - acc[j - 1]) * -np.expm1(-(edges_s[k + 1] - seg_start[j]) / tau_s)
    y = np.empty(n + 1)
    y[0] = acc[0]  # settled: at rest long before the run
    y[1:], _ = lfilter([1.0], [1.0, -a], forcing, zi=[a * y[0]])
    return (np.diff(u_integral) - tau_s * np.diff(y)) / period_s


def read_at_edge(period_mean_g: np.ndarray, duty: np.ndarray, period_s: float, range_g: float) -> np.ndarray:
    """The filtered signal where each duty cycle ends (SensorParams.dcm_reading = "edge"),
    from its period means: the edge comes (duty − ½)·T2 after the period's middle, where
    the signal moves at the slope of its period means (to first order: the shift is at
    most a tenth of a period for |a| ≤ 1.6 g, the signal a one-pole response that bends
    little within it)."""
    slope_g_per_s = np.gradient(period_mean_g, period_s) if period_mean_g.size > 1 else np.zeros(1)
    return np.clip(period_mean_g + (duty - 0.5) * period_s * slope_g_per_s, -range_g, range_g)


def filtered_white_noise(rng: np.random.Generator, n: int, period_s: float, sensor: SensorParams) -> np.ndarray:
    """White noise of the data sheet's density through the one-pole filter, sampled exactly.

    The filtered noise is an Ornstein–Uhlenbeck process: its exact discretisation is
    AR(1) with a = e^(−2π f Ts) and innovation variance σ²(1 − a²), σ² = N²·π/2·f.
    """
    sigma = sensor.noise_rms_g
    a = np.exp(-2.0 * np.pi * sensor.bandwidth_hz * period_s)
    w = rng.standard_normal(n) * sigma * np.sqrt(1.0 - a * a)
    w[0] = rng.standard_normal() * sigma  # stationary start
    y, _ = lfilter([1.0], [1.0, -a], w, zi=[0.0])
    return y


def timer_counts(edges_s: np.ndarray, duty_x, duty_y, tick_hz: float, rng: np.random.Generator):
    """8051 capture: each edge is latched as floor(t·f + phase); T1, T2 are differences of latches.

    Because T2 counts are differences of successive latches, their sum telescopes: the
    board-derived time never drifts from the true time by more than one tick.
    """
    phase = rng.uniform()
    latch = np.floor(edges_s * tick_hz + phase).astype(np.int64)
    t2 = np.diff(latch)
    starts = edges_s[:-1]
    periods = np.diff(edges_s)
    fall_x = np.floor((starts + duty_x * periods) * tick_hz + phase).astype(np.int64)
    fall_y = np.floor((starts + duty_y * periods) * tick_hz + phase).astype(np.int64)
    return fall_x - latch[:-1], fall_y - latch[:-1], t2


def simulate(
    profile: PiecewiseConstantAcceleration,
    sensor: SensorParams = BOARD_SENSOR,
    seed: int = 0,
    error_terms: tuple[ErrorTerm, ...] = (),
    host: HostLinkParams = BOARD_HOST_LINK,
    duration_s: float | None = None,
) -> SimulatedRun:
    """Simulate the board's sample stream for a motion (along the sensor's X axis)."""
    duration_s = profile.duration_s if duration_s is None else duration_s
    period_s = sensor.t2_s
    n = int(np.floor(duration_s / period_s)) + 1
    if n < 2:
        raise ValueError("the run must last at least two sensor periods")
    edges_s = np.arange(n + 1) * period_s
    t_s = edges_s[:-1]
    pos, vel, acc = profile.evaluate(t_s)
    temp_c = np.full(n, sensor.temperature_c)
    ctx = SignalContext(t_s, pos, vel, acc, temp_c, sensor, seed, profile=profile)

    true_x_g = period_mean_lowpass(profile, n, period_s, sensor.bandwidth_hz) / STANDARD_GRAVITY_MPS2
    true_y_g = np.zeros(n)
    ctx.motion_x_g = true_x_g
    axes = []
    for name, true_g, axis in (("x", true_x_g, sensor.x), ("y", true_y_g, sensor.y)):
        sensed = true_g + filtered_white_noise(ctx.rng(f"noise_{name}"), n, period_s, sensor)
        sensed = sensed + axis.zero_g_offset_g + drift_g(t_s, axis.drift)
        axes.append(sensed)
    acc_x_g, acc_y_g = axes
    for term in error_terms:
        acc_x_g, acc_y_g = term.acceleration_g(ctx, acc_x_g, acc_y_g)

    duties = []
    for sensed, axis in ((acc_x_g, sensor.x), (acc_y_g, sensor.y)):
        sensed = np.clip(sensed, -sensor.range_g, sensor.range_g)
        duty = 0.5 + 0.125 * (1.0 + axis.sensitivity_error_frac) * sensed
        if sensor.dcm_reading == "edge":
            sensed = read_at_edge(sensed, duty, period_s, sensor.range_g)
            duty = 0.5 + 0.125 * (1.0 + axis.sensitivity_error_frac) * sensed
        duties.append(duty)
    t1x, t1y, t2 = timer_counts(edges_s, duties[0], duties[1], sensor.tick_hz, ctx.rng("timer"))

    latency = ctx.rng("host").exponential(host.latency_mean_s, n)
    t_host_s = edges_s[1:] + host.frame_time_s + latency
    t_host_s = np.maximum.accumulate(t_host_s)  # a serial line delivers in order

    run = SimulatedRun(
        tick_hz=sensor.tick_hz,
        seq=np.arange(n, dtype=np.int64) % SEQ_MODULUS,
        t1x=t1x,
        t1y=t1y,
        t2=t2,
        flags=np.zeros(n, dtype=np.int64),
        t_s=t_s,
        t_host_s=t_host_s,
        temp_c=temp_c,
        ref_pos_m=pos,
        ref_vel_mps=vel,
        ref_acc_mps2=acc,
    )
    for term in error_terms:
        run = term.samples(ctx, run)
    return run
