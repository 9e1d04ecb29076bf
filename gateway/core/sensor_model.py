"""The ADXL202 and the 8051 timer as the simulator sees them.

Defaults are the paper's setup and the data sheets' numbers; each says where it comes
from. Values the paper does not give are marked "assumed" with the reasoning.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gateway.core.drift_model import DriftModel
from gateway.core.units import DEFAULT_TICK_HZ, STANDARD_GRAVITY_MPS2

# A calibrated part's sensitivity is known to about ±1 % (data sheet: 10–15 %/g before
# calibration; a two-point calibration leaves the reference's own uncertainty). The
# diagnosis calls a scale error within it the setup's own; the estimator's σ carries it.
CALIBRATED_SENSITIVITY_TOLERANCE_FRAC = 0.01
# ADXL202 data sheet: f−3dB = 1 / (2π · 32 kΩ · C)
INTERNAL_FILTER_RESISTOR_OHM = 32e3
# ADXL202 data sheet: T2 = RSET / 125 MΩ
T2_PER_OHM_S = 1.0 / 125e6


@dataclass(frozen=True)
class AxisSensor:
    """One axis of the part as built, relative to its nominal calibration (D0 = 0.5, S = 12.5 %/g).

    zero_g_offset_g: the part's zero-g error (data sheet: large part to part). Assumed
        10 mg on X; the gateway removes it by reference-point compensation at rest.
    sensitivity_error_frac: the part's sensitivity error; 0 in the baseline (the
        scale_factor effect of the diagnosis adds it).
    drift: the paper's exponential zero drift. Its fig. 1 values are not legible in the
        source; assumed C1 = 2.5 mg (the size of the random bias drift Liu & Pang report
        for the ADXL202), C2 = 0 (ε(0) is part of the zero-g offset), T = 30 min (a
        warm-up time constant).
    """

    zero_g_offset_g: float = 0.0
    sensitivity_error_frac: float = 0.0
    drift: DriftModel = DriftModel(c1_g=0.0025, c2_g=0.0, time_constant_s=1800.0)


DCM_READINGS = ("mean", "edge")  # SensorParams.dcm_reading
# board protocol: the duty cycle changes by S = 12.5 % per g
NOMINAL_DUTY_PER_G = 0.125


def edge_reading_gain_s2_per_m(period_s: float) -> float:
    """S·T2/2g: a sample read where its duty cycle ends comes S·T2·a/g after the period's
    middle, so it reads a + S·T2/2g · d(a²)/dt (SensorParams.dcm_reading = "edge")."""
    return NOMINAL_DUTY_PER_G * period_s / (2.0 * STANDARD_GRAVITY_MPS2)


def edge_reading_excess_mps2(motion_mps2: np.ndarray, spacing, period_s: float) -> np.ndarray:
    """What an edge reading adds to a motion's acceleration: S·T2/2g · d(a²)/dt (spacing: the
    sample times, or one period for a regular grid)."""
    return edge_reading_gain_s2_per_m(period_s) * np.gradient(motion_mps2 * motion_mps2, spacing)


@dataclass(frozen=True)
class SensorParams:
    x: AxisSensor = AxisSensor(zero_g_offset_g=0.010)
    y: AxisSensor = AxisSensor(zero_g_offset_g=-0.006)
    # ADXL202E data sheet: noise floor 200 µg/√Hz rms.
    noise_density_g_per_rthz: float = 200e-6
    # CX = CY = 0.1 µF gives f−3dB ≈ 50 Hz, below the 250 Hz Nyquist rate of 500 samples/s
    # (assumed: the paper does not give its capacitors; 0.1 µF is the evaluation board's
    # common choice for 50 Hz).
    filter_capacitor_f: float = 0.1e-6
    range_g: float = 2.0
    # Board default (board-protocol.md): RSET = 250 kΩ, T2 ≈ 2.0 ms.
    rset_ohm: float = 250e3
    # The part's T2 error against RSET/125 MΩ. Assumed +0.5 %: the data sheet gives the
    # formula, not its tolerance; a 1 % RSET and the internal oscillator make a few ‰.
    t2_error_frac: float = 0.005
    # 8051 at 11.0592 MHz, timer at crystal/12.
    tick_hz: float = DEFAULT_TICK_HZ
    # Board temperature (°C) reported in STATUS; constant in the baseline.
    temperature_c: float = 25.0
    # Where in its period the duty-cycle modulator reads the filtered signal — the data
    # sheet does not say. "mean": the period's mean (an integrating modulator, the
    # simulator's convention until 2026-11-27); "edge": the value at the moment the duty
    # cycle ends (natural sampling: the signal compared with a ramp), which reads each
    # sample S·T2·a/g later than the period's middle for an acceleration a — a reading of
    # a + (S·T2/2g)·d(a²)/dt, whose integral leaves (S·T2/2g)·∫a² dt of position per move,
    # of one sign whichever way the axis moves (0.25 mm per 30 cm stroke of the paper's).
    dcm_reading: str = "mean"

    def __post_init__(self) -> None:
        if self.dcm_reading not in DCM_READINGS:
            raise ValueError(f"dcm_reading must be one of {', '.join(DCM_READINGS)}")
        for name in ("noise_density_g_per_rthz",):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative")
        for name in ("filter_capacitor_f", "range_g", "rset_ohm", "tick_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")

    @property
    def bandwidth_hz(self) -> float:
        return 1.0 / (2.0 * math.pi * INTERNAL_FILTER_RESISTOR_OHM * self.filter_capacitor_f)

    @property
    def t2_nominal_s(self) -> float:
        return self.rset_ohm * T2_PER_OHM_S

    @property
    def t2_s(self) -> float:
        return self.t2_nominal_s * (1.0 + self.t2_error_frac)

    @property
    def noise_rms_g(self) -> float:
        """White noise through a one-pole filter: noise bandwidth = π/2 · f−3dB."""
        return self.noise_density_g_per_rthz * math.sqrt(math.pi / 2.0 * self.bandwidth_hz)


# the board as built (the values above); frozen, so one shared instance is a safe default argument
BOARD_SENSOR = SensorParams()


@dataclass(frozen=True)
class HostLinkParams:
    """How samples reach the host: UART time of a frame plus OS/USB latency.

    15-byte SAMPLE at 115 200 baud 8N1 = 150 bits ≈ 1.30 ms. Host latency assumed
    exponential with 0.2 ms mean (a USB-serial adapter with low-latency timer).
    """

    baud: int = 115_200
    frame_bytes: int = 15
    latency_mean_s: float = 0.2e-3

    @property
    def frame_time_s(self) -> float:
        return self.frame_bytes * 10 / self.baud


# the link as assumed above; frozen, so one shared instance is a safe default argument
BOARD_HOST_LINK = HostLinkParams()
