"""Error terms the baseline simulator lacks, each one small ErrorTerm (simulator.py).

They make measured-like recordings for the diagnosis tests and benchmark: a test picks
one or two with random parameters, and `adxlgw diagnose` must find them without being
told. The diagnosis never imports this module (a test checks it).

Documented effect sizes (what the benchmark draws from, `EFFECT_SIZES`) are chosen to
be physically plausible for an ADXL202 on a robot and visible in a 4-stroke run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gateway.core.filters import mount_resonance, one_pole_lowpass
from gateway.core.sensor_model import BOARD_HOST_LINK
from gateway.core.simulator import ErrorTerm, SignalContext


def _sensed_motion_g(ctx: SignalContext) -> np.ndarray:
    return ctx.motion_x_g


@dataclass
class ScaleFactorTerm(ErrorTerm):
    scale_error_frac: float
    name = "scale_factor"

    def acceleration_g(self, ctx, ax, ay):
        # the part's sensitivity error acts on everything the element senses
        return ax * (1.0 + self.scale_error_frac), ay


@dataclass
class PathTiltTerm(ErrorTerm):
    """The rail is not level: the tilt changes by gradient_rad_per_m along the path."""

    gradient_rad_per_m: float
    name = "tilt"

    def acceleration_g(self, ctx, ax, ay):
        return ax + np.sin(self.gradient_rad_per_m * ctx.ref_pos_m), ay


@dataclass
class CrossAxisTerm(ErrorTerm):
    """The motion leaks into the other axis: y reads gain·a (misalignment, cross-axis sensitivity)."""

    gain: float
    name = "cross_axis"

    def acceleration_g(self, ctx, ax, ay):
        return ax, ay + self.gain * _sensed_motion_g(ctx)


@dataclass
class TemperatureTerm(ErrorTerm):
    """Offset k·(T_die − 25 °C) with a board temperature that swings (a fan cycling, the robot's duty).

    The board's thermometer reads the board; the accelerometer's die follows it through its
    package, a thermal RC of time constant die_lag_s (0: the die at the board's
    temperature). The swing has gone on before the record: the die is in its periodic
    steady state, the board's swing scaled by 1/√(1 + (ωτ)²) and delayed by atan(ωτ)/ω."""

    offset_g_per_c: float
    swing_c: float = 4.0
    cycle_s: float = 6.0
    phase_rad: float | None = None  # the swing's phase at t = 0; None: drawn per recording
    die_lag_s: float = 0.0
    name = "temperature_offset"

    def _temp(self, ctx, t, lag_s=0.0):
        phase = float(ctx.rng("temperature").uniform(0.0, 2.0 * math.pi))
        if self.phase_rad is not None:
            phase = self.phase_rad
        wt = 2.0 * math.pi / self.cycle_s * lag_s
        return 25.0 + self.swing_c / math.hypot(1.0, wt) * np.sin(2.0 * math.pi * t / self.cycle_s + phase
                                                                 - math.atan(wt))

    def acceleration_g(self, ctx, ax, ay):
        temp = self._temp(ctx, ctx.t_s, self.die_lag_s)  # the die's
        # the recording's temp_c is the board's latest STATUS value (recording format):
        # the temperature measured once per second (at a phase of the board's own), in
        # 0.01 °C, held until the next report
        report_phase_s = float(ctx.rng("status reports").uniform(0.0, 1.0))
        reported_at = np.floor(ctx.t_s - report_phase_s) + report_phase_s
        ctx.temp_c[:] = np.round(self._temp(ctx, reported_at), 2)
        return ax + self.offset_g_per_c * (temp - 25.0), ay

    def samples(self, ctx, run):
        run.temp_c = ctx.temp_c.copy()
        return run


@dataclass
class VibrationTerm(ErrorTerm):
    frequency_hz: float
    damping_ratio: float
    name = "vibration"

    def acceleration_g(self, ctx, ax, ay):
        motion = _sensed_motion_g(ctx)
        ring = mount_resonance(motion, ctx.sensor.t2_s, self.frequency_hz, self.damping_ratio) - motion
        return ax + ring, ay


@dataclass
class BandwidthTerm(ErrorTerm):
    cutoff_hz: float
    name = "bandwidth"

    def acceleration_g(self, ctx, ax, ay):
        motion = _sensed_motion_g(ctx)
        return ax + (one_pole_lowpass(motion, ctx.sensor.t2_s, self.cutoff_hz) - motion), ay


@dataclass
class NonlinearityTerm(ErrorTerm):
    quadratic_per_g: float
    name = "nonlinearity"

    def acceleration_g(self, ctx, ax, ay):
        return ax + self.quadratic_per_g * ax * ax, ay


@dataclass
class ClippingTerm(ErrorTerm):
    limit_g: float
    name = "clipping"

    def acceleration_g(self, ctx, ax, ay):
        return np.clip(ax, -self.limit_g, self.limit_g), ay


@dataclass
class BiasRandomWalkTerm(ErrorTerm):
    k_g_per_rts: float
    name = "bias_random_walk"

    def acceleration_g(self, ctx, ax, ay):
        dt = np.diff(ctx.t_s, prepend=ctx.t_s[0])
        walk = np.cumsum(ctx.rng("bias_walk").standard_normal(ax.size) * np.sqrt(dt)) * self.k_g_per_rts
        return ax + walk, ay


@dataclass
class ReferenceDelayTerm(ErrorTerm):
    """The reference is logged delay_s late: the recorded reference at t is the motion at t − d."""

    delay_s: float
    name = "reference_delay"

    def samples(self, ctx, run):
        run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2 = ctx.profile.evaluate(run.t_s - self.delay_s)
        return run


@dataclass
class SampleLossTerm(ErrorTerm):
    """Frames lost on the line in short bursts (noise on RS-232, a full buffer)."""

    lost_fraction: float
    mean_burst: float = 2.0
    name = "sample_loss"

    def samples(self, ctx, run):
        rng = ctx.rng("loss")
        n = len(run)
        starts = rng.random(n) < self.lost_fraction / self.mean_burst
        keep = np.ones(n, dtype=bool)
        for i in np.flatnonzero(starts):
            keep[i:i + int(rng.geometric(1.0 / self.mean_burst))] = False
        keep[:10] = True
        keep[-10:] = True
        return run.select(keep)


# A USB-serial adapter's buffer (FTDI FT232R/FT232H data sheets, application note
# AN232B-04 "Data throughput, latency and handshaking"): a full-speed bulk packet is 64
# bytes, two of them the chip's modem status, so 62 data bytes; the chip sends what it
# holds when the packet is full or when its latency timer (1–255 ms, default 16) expires,
# the timer restarting at each packet sent (with an empty buffer only the status goes).
# The host reads a packet at once: every frame whose last byte it holds gets one stamp.
USB_PACKET_DATA_BYTES = 62
UART_BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop


def buffered_arrivals_s(frame_done_s: np.ndarray, frame_bytes: int, baud: float, latency_timer_s: float,
                        packet_bytes: int, timer_phase_s: float) -> np.ndarray:
    """When each frame reaches the host through an adapter that buffers (above): the
    time its last byte's packet leaves the chip. frame_done_s: when each frame's last
    byte left the UART (sorted); the bytes before it left one byte time apart."""
    byte_s = UART_BITS_PER_BYTE / baud
    offsets = (np.arange(frame_bytes) - (frame_bytes - 1)) * byte_s
    byte_times = (frame_done_s[:, None] + offsets[None, :]).ravel()
    sent_s = np.empty(byte_times.size)
    timer_start = -timer_phase_s
    held: list[int] = []  # bytes in the chip's buffer, waiting
    for i, b in enumerate(byte_times):
        if held and b >= timer_start + latency_timer_s:  # the timer expired with data: a short packet
            timer_start += latency_timer_s
            sent_s[held] = timer_start
            held = []
        if not held and b >= timer_start + latency_timer_s:  # it expired empty (status only), restarted
            timer_start += latency_timer_s * np.floor((b - timer_start) / latency_timer_s)
        held.append(i)
        if len(held) == packet_bytes:  # a full packet leaves at once
            sent_s[held] = b
            held = []
            timer_start = b
    if held:
        sent_s[held] = timer_start + latency_timer_s
    return sent_s.reshape(frame_done_s.size, frame_bytes)[:, -1]


@dataclass
class TimingTerm(ErrorTerm):
    """Host arrival times through a buffering USB-serial adapter, on a host clock that
    is corrected while the record runs.

    - the adapter (buffered_arrivals_s): 62-byte packets, sent when full or when the
      latency timer expires; every frame in one packet is stamped at once;
    - the host reads each packet after an exponential latency (the baseline link's);
    - the host clock runs off by clock_rate_error (NTP slews an offset below its 128 ms
      step threshold at up to 500 ppm; ntpd's documented maximum) and is stepped once by
      clock_step_s at step_at (a fraction of the record; chrony's makestep, a PTP or
      manual correction): a step back makes arrival times go backwards.
    """

    latency_timer_s: float
    clock_step_s: float = 0.0
    clock_rate_error: float = 0.0
    step_at: float = 0.5
    packet_bytes: int = USB_PACKET_DATA_BYTES
    name = "timing"
    _hold_back_s: float = float("nan")

    def samples(self, ctx, run):
        rng = ctx.rng("usb")
        link = BOARD_HOST_LINK
        period = ctx.sensor.t2_s
        done = run.t_s + period + link.frame_time_s  # the frame's last byte leaves the UART
        sent = buffered_arrivals_s(done, link.frame_bytes, link.baud, self.latency_timer_s, self.packet_bytes,
                                   float(rng.uniform(0.0, self.latency_timer_s)))
        # one read latency per packet: frames sent together are stamped together
        # the waits' spread, without the last packet (sent when the record ends, by the timer)
        last = sent < sent[-1]
        self._hold_back_s = math.sqrt(12.0) * float(np.std((sent - done)[last])) if last.any() else 0.0
        packet = np.concatenate([[0], np.cumsum(np.diff(sent) > 0)])
        read = sent + rng.exponential(link.latency_mean_s, packet[-1] + 1)[packet]
        t0 = float(run.t_s[0])
        step_time = t0 + self.step_at * float(run.t_s[-1] - t0)
        run.t_host_s = read + self.clock_rate_error * (read - t0) + np.where(read >= step_time, self.clock_step_s, 0.0)
        return run

    def equivalent_hold_back_s(self) -> float:
        """The adapter's waits in the record made, as the width of the uniform wait with
        their spread (√12·σ: exact when the frames meet the flushes at all phases, the
        latency timer's; a packet filling makes its waits uneven). Set by samples()."""
        return self._hold_back_s


# Documented effect sizes: (low, high) of a uniform draw per parameter (sign random where ±).
EFFECT_SIZES = {
    "scale_factor": {"scale_error_frac": (0.01, 0.03)},
    "tilt": {"gradient_rad_per_m": (0.03, 0.09)},  # 0.5–1.5° over a 30 cm stroke
    "cross_axis": {"gain": (0.02, 0.06)},
    "temperature_offset": {"offset_g_per_c": (0.5e-3, 2e-3)},
    "vibration": {"frequency_hz": (12.0, 40.0), "damping_ratio": (0.03, 0.12)},
    "bandwidth": {"cutoff_hz": (8.0, 25.0)},
    "nonlinearity": {"quadratic_per_g": (0.005, 0.015)},
    "clipping": {"limit_g": (0.6, 0.9)},
    "bias_random_walk": {"k_g_per_rts": (0.2e-3, 0.6e-3)},  # on a 60 s standstill (SCENARIO_FOR)
    "reference_delay": {"delay_s": (0.004, 0.012)},
    "sample_loss": {"lost_fraction": (0.002, 0.01)},
    # a latency timer of 4–16 ms (16: the FTDI default); a clock step of up to 30 ms either
    # way; a slew within ntpd's 500 ppm
    "timing": {"latency_timer_s": (0.004, 0.016), "clock_step_s": (-0.030, 0.030),
               "clock_rate_error": (-500e-6, 500e-6), "step_at": (0.1, 0.9)},
}
# A bias random walk is a standstill phenomenon (as the paper's drift model is): it is
# diagnosed on a standstill record, where no motion regressor can mimic it. A 4-stroke run
# (7.6 s) is too short to tell a walk from the fitted offset and drift.
SCENARIO_FOR = {"bias_random_walk": ("standstill", 60.0)}
SIGNED = {"scale_factor", "tilt", "cross_axis", "temperature_offset", "nonlinearity", "reference_delay"}

TERMS = {
    "scale_factor": ScaleFactorTerm, "tilt": PathTiltTerm, "cross_axis": CrossAxisTerm,
    "temperature_offset": TemperatureTerm, "vibration": VibrationTerm, "bandwidth": BandwidthTerm,
    "nonlinearity": NonlinearityTerm, "clipping": ClippingTerm, "bias_random_walk": BiasRandomWalkTerm,
    "reference_delay": ReferenceDelayTerm, "sample_loss": SampleLossTerm, "timing": TimingTerm,
}


def draw_effect(name: str, rng: np.random.Generator) -> ErrorTerm:
    """One effect at a random documented size."""
    params = {}
    for p, (lo, hi) in EFFECT_SIZES[name].items():
        v = float(rng.uniform(lo, hi))
        if name in SIGNED and rng.random() < 0.5:
            v = -v
        params[p] = v
    return TERMS[name](**params)
