"""Settings of the gateway's estimator, derived from a sensor model — never tuned to a recording.

Every number the filter uses comes from one of three sources, each documented below:
the sensor model (data sheet + 8051 timer: `from_sensor_model`), a fitted drift model
(`adxlgw fit-drift`: `from_sensor_model(..., drift_fit=...)`), or, for a foreign sensor
with no model, the recording's own initial rest (`from_rest`). The few application
choices (how long a window, how slow a cruise may be) are fields with defaults that say
why.

Noise conventions (as gateway/core/drift_fit.py):
    N  one-sided white-noise density of the acceleration (m/s²/√Hz, data-sheet style).
       Integrated, it gives a velocity random walk Var(v(t)) = N²·t/2, so the
       continuous process noise on velocity is N²/2; one sample's white-equivalent
       variance is N²/(2·Ts) (what the sample mean of a standstill averages down).
    K  bias random walk (m/s²/√s): Var(b(t)) = K²·t.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

# not scipy: its import was ~0.6 s of the daemon's start (a restart's blind time) and
# scipy 143 MB of the daemon's install (gateway/core/chi2.py)
from gateway.core.chi2 import chi2_isf
from gateway.core.drift_fit import FittedDrift, allan_deviation, autocorrelation
from gateway.core.sensor_model import (
    BOARD_SENSOR,
    CALIBRATED_SENSITIVITY_TOLERANCE_FRAC,
    NOMINAL_DUTY_PER_G,
    SensorParams,
    edge_reading_gain_s2_per_m,
)
from gateway.core.units import STANDARD_GRAVITY_MPS2

G = STANDARD_GRAVITY_MPS2
ACF_LAGS = 32  # enough to cover the noise correlation of any window we use
ZERO_G_DUTY = 0.5
SENSITIVITY_DUTY_PER_G = NOMINAL_DUTY_PER_G


@dataclass(frozen=True)
class EstimatorSettings:
    sample_period_s: float
    # N: one-sided white-equivalent density (the low-frequency level that integration sees)
    accel_white_density_mps2_per_rthz: float
    # one sample's standard deviation at rest and the noise autocorrelation (lags 1, 2, …):
    # what a window of samples shows, for the variance test of the standstill detector
    sample_noise_std_mps2: float
    noise_autocorrelation: tuple[float, ...]
    # K: how fast the bias may wander beyond the drift model
    bias_random_walk_mps2_per_rts: float
    # the filter starts knowing nothing about the bias: 1 g covers any zero-g offset and
    # gravity on a tilted axis; the first standstill measures it
    bias_initial_std_mps2: float = G
    # deterministic zero drift ε(t) = C1(1 − e^(−t/T)) (C2 is part of the unknown offset),
    # counted from power-on; drift_start_s = time since power-on at t_s = 0
    drift_c1_mps2: float = 0.0
    drift_time_constant_s: float = 1800.0
    drift_start_s: float = 0.0
    # standstill detector (gateway/core/standstill.py). The window is the shortest quiet
    # time that counts as a standstill: 0.1 s is 30 noise correlation times of the ADXL's
    # 50 Hz filter and a tenth of the paper's 1 s dwell.
    standstill_window_s: float = 0.1
    # false "motion" per window at rest (variance test); a false motion costs only a
    # moment of dead reckoning, a false standstill costs a wrong velocity reset
    standstill_false_motion_prob: float = 1e-4
    standstill_mean_sigmas: float = 5.0
    standstill_velocity_sigmas: float = 5.0
    # Application choice: the slowest cruise that must never be called a standstill.
    # The velocity test accepts a standstill only if |v| ≤ this floor and 5σ_v ≤ it (else
    # it cannot tell a cruise at the floor speed from a stop: undecidable, flag 256); the
    # floor covers errors the model lacks (tilt, scale). 0.1 m/s is a tenth of the
    # paper's 1 m/s cruise.
    standstill_speed_floor_mps: float = 0.1
    # A window whose acceleration (bias removed) swings the velocity by less than this is
    # a vibrating mount, not motion: the robot arm of datasets/leiria-robot settles for
    # ~0.5 s after each stop with 1.5–2× the initial rest's noise, a swing of ≤ 3 mm/s in
    # 90 % of its rest windows (cruise windows: 3–5 mm/s, told apart by the velocity
    # test); a start of motion swings it by cm/s within a window.
    standstill_vibration_mps: float = 0.005
    # The largest step of the offset between two stops that a machine's "at rest" hint may
    # explain (a tilt change of 1.1°, a knock on the mount, a temperature step): 20 mg,
    # twice the largest of issue 13's cases. A hinted rest whose window mean is further off
    # the bias is an axis still decelerating: the hint is flagged, not obeyed.
    offset_step_max_mps2: float = 0.02 * G
    # The axis's travel: highest − lowest position it can reach (a plant fact: its soft
    # limits; the daemon's estimator.travel_m). It bounds how long a cruise can last (see
    # quiet_stop_s). 20 m: the daemon's default travel, ±10 m.
    travel_span_m: float = 20.0
    # After a restart or a board reset that may come mid-move (RealtimeEstimator.restart):
    # the velocity is unknown within the machine's speed. 2 m/s: twice the paper's cruise
    # and the robot's fastest programmed speed.
    restart_speed_std_mps: float = 2.0
    # How long the machine's "moving" may lead the motion the sensor sees: the controller
    # drops "in position" when it commands the move, the axis follows after a PLC cycle
    # (10–20 ms), a fieldbus and a servo's lag, and the hint and the sensor are on two
    # clocks. For this long after "at rest" a "moving" hint forbids no stop (it is
    # unknown there); after it, it does. 0.1 s: the same order as the detector's window.
    hint_latency_s: float = 0.1
    # A body at rest has v = 0 exactly; this only keeps the update regular.
    zupt_velocity_std_mps: float = 1e-5
    # Time constant of the sensor's own low-pass filter, 1/(2π f−3dB): the outputs undo
    # its lag (ADXL202: CX = 0.1 µF → 3.2 ms; a 1 m/s cruise reads 3 mm short without).
    # 0 when unknown (a foreign sensor).
    sensor_lag_s: float = 0.0
    # an invalid or lost sample in motion: its acceleration is unknown within the range
    missing_acc_std_mps2: float = 2.0 * G / math.sqrt(3.0)
    # How well the sensitivity is known (1σ, a fraction). A sensitivity off by s reads every
    # acceleration (1 + s)·a; the bias is measured at rest, so the velocity is off by s·v and
    # the position by s·(p − p_tare) — at any stop, whatever the stops' updates did (they
    # see v = 0 either way). The filter cannot see it; the reported σ must carry it. 0.5 %:
    # a calibrated part known to ±1 % (sensor_model.CALIBRATED_SENSITIVITY_TOLERANCE_FRAC),
    # read as 2σ. A part within that tolerance left 25 % of the simulator's stop errors
    # outside ±3σ without it (benchmarks/accuracy/sigma_coverage.py).
    sensitivity_std_frac: float = CALIBRATED_SENSITIVITY_TOLERANCE_FRAC / 2.0
    # A duty-cycle part (the ADXL202) whose modulator may read the signal where the duty
    # cycle ends rather than over the period (SensorParams.dcm_reading; the data sheet
    # does not say): such a reading adds (S·T2/2g)·∫a² dt of position per move, of one
    # sign (0.25 mm per stroke of the paper's). Not corrected — which reading a board has
    # is not known — but carried in the reported σ (kernel_output.reading_instant_var).
    # On the simulator with edge readings, 69–70 % of the stop errors lay inside ±3σ
    # without it (benchmarks/accuracy/sigma_coverage.py --dcm-reading edge). False for other sensors: an ADC
    # samples at a fixed instant.
    duty_cycle_reading_unknown: bool = False
    source: str = "defaults"

    def __post_init__(self) -> None:
        positive = ("sample_period_s", "accel_white_density_mps2_per_rthz", "sample_noise_std_mps2",
                    "standstill_window_s", "drift_time_constant_s", "zupt_velocity_std_mps", "travel_span_m")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value!r}")
        for name in ("bias_random_walk_mps2_per_rts", "bias_initial_std_mps2", "missing_acc_std_mps2",
                     "standstill_speed_floor_mps", "sensor_lag_s", "standstill_vibration_mps",
                     "offset_step_max_mps2", "restart_speed_std_mps", "hint_latency_s",
                     "sensitivity_std_frac"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be ≥ 0 and finite, got {value!r}")
        if not 0 < self.standstill_false_motion_prob < 1:
            raise ValueError("standstill_false_motion_prob must be in (0, 1)")

    # ---- derived once, used by the kernel -------------------------------------------
    @property
    def velocity_noise_density(self) -> float:
        """Continuous process noise on velocity, (m/s²)²/Hz = N²/2."""
        return self.accel_white_density_mps2_per_rthz**2 / 2.0

    @property
    def zaru_variance_mps2_sq(self) -> float:
        """One sample's white-equivalent variance, N²/(2·Ts): the ZARU measurement noise."""
        return self.accel_white_density_mps2_per_rthz**2 / (2.0 * self.sample_period_s)

    @property
    def window_samples(self) -> int:
        from gateway.core.standstill import MIN_WINDOW_SAMPLES

        return max(MIN_WINDOW_SAMPLES, int(round(self.standstill_window_s / self.sample_period_s)))

    @property
    def window_dof(self) -> float:
        """Effective degrees of freedom of a window's sample variance for correlated noise.

        Var(s²) ≈ 2σ⁴/ν with ν = W / (1 + 2 Σ (1 − k/W) ρ_k²) (Bartlett).
        """
        w = self.window_samples
        rho = np.asarray(self.noise_autocorrelation[: w - 1], dtype=float)
        k = np.arange(1, rho.size + 1)
        return float(w / (1.0 + 2.0 * np.sum((1.0 - k / w) * rho**2)))

    @property
    def window_variance_threshold_mps2_sq(self) -> float:
        """Reject standstill above this window variance: σ²·χ²_ν(1 − p)/ν."""
        nu = self.window_dof
        return self.sample_noise_std_mps2**2 * chi2_isf(self.standstill_false_motion_prob, nu) / nu

    @property
    def quiet_stop_s(self) -> float:
        """How long a quiet stretch the velocity test cannot decide (the filter lost its
        velocity: an outage, a restart) must last to be a stop. A cruise is at least the
        speed floor (the slowest motion that must never be called a standstill), so a
        cruise longer than travel / floor would leave the axis's travel: a quiet stretch
        longer than that is no cruise. A physical bound from what the plant knows, not a
        time taken from one machine; no floor (0): never."""
        if self.standstill_speed_floor_mps <= 0.0:
            return math.inf
        return self.travel_span_m / self.standstill_speed_floor_mps

    @property
    def zupt_chi2_threshold(self) -> float:
        """A stop's velocity innovation beyond this χ² (1 dof) at the same false-alarm rate as
        the variance test is no chance: the stop and the integrated motion disagree."""
        return float(chi2_isf(self.standstill_false_motion_prob, 1))

    def kernel_params(self) -> np.ndarray:
        """The flat float array the compiled kernel reads (layout: estimator_kernel.P_*)."""
        from gateway.core import estimator_kernel as k

        p = np.zeros(k.N_PARAMS)
        p[k.P_QV] = self.velocity_noise_density
        p[k.P_QB] = self.bias_random_walk_mps2_per_rts**2
        p[k.P_R] = self.zaru_variance_mps2_sq
        p[k.P_DRIFT_C1] = self.drift_c1_mps2
        p[k.P_DRIFT_T] = self.drift_time_constant_s
        p[k.P_DRIFT_T0] = self.drift_start_s
        p[k.P_WINDOW] = self.window_samples
        p[k.P_VAR_MAX] = self.window_variance_threshold_mps2_sq
        p[k.P_MEAN_SIGMAS] = self.standstill_mean_sigmas
        p[k.P_VEL_SIGMAS] = self.standstill_velocity_sigmas
        p[k.P_SPEED_FLOOR] = self.standstill_speed_floor_mps
        p[k.P_R_ZUPT] = self.zupt_velocity_std_mps**2
        p[k.P_MISSING_VAR] = self.missing_acc_std_mps2**2
        p[k.P_BIAS0_VAR] = self.bias_initial_std_mps2**2
        p[k.P_LAG] = self.sensor_lag_s
        p[k.P_QUIET_STOP_S] = self.quiet_stop_s
        p[k.P_VIBRATION] = self.standstill_vibration_mps
        p[k.P_STEP_MAX] = self.offset_step_max_mps2
        p[k.P_RESTART_VEL_VAR] = self.restart_speed_std_mps**2
        p[k.P_HINT_LATENCY] = self.hint_latency_s
        p[k.P_SCALE_VAR] = self.sensitivity_std_frac**2
        # per second of T2 (the kernel multiplies by each sample's period)
        p[k.P_READING_INSTANT] = edge_reading_gain_s2_per_m(1.0) if self.duty_cycle_reading_unknown else 0.0
        p[k.P_ZUPT_CHI2] = self.zupt_chi2_threshold
        return p

    def with_known_bias(self) -> EstimatorSettings:
        """The noise floor: the same filter told the true bias (fed z − b_true, bias fixed at 0)."""
        return replace(self, bias_initial_std_mps2=0.0, bias_random_walk_mps2_per_rts=0.0,
                       drift_c1_mps2=0.0, source=self.source + " + true bias (noise floor)")

    def describe(self) -> list[str]:
        return [
            f"source: {self.source}",
            f"sample period {self.sample_period_s * 1e3:.4g} ms; white noise N = "
            f"{self.accel_white_density_mps2_per_rthz / G * 1e6:.1f} µg/√Hz; per-sample σ = "
            f"{self.sample_noise_std_mps2 / G * 1e3:.3g} mg",
            f"bias random walk K = {self.bias_random_walk_mps2_per_rts / G * 1e6:.3g} µg/√s; drift C1 = "
            f"{self.drift_c1_mps2 / G * 1e3:.3g} mg, T = {self.drift_time_constant_s:.4g} s",
            f"standstill: window {self.window_samples} samples, variance ≤ "
            f"{math.sqrt(self.window_variance_threshold_mps2_sq) / G * 1e3:.3g} mg rms (or a vibration swinging "
            f"the velocity ≤ {self.standstill_vibration_mps * 1e3:g} mm/s), "
            f"|v| ≤ {self.standstill_speed_floor_mps:g} m/s "
            f"known to {self.standstill_velocity_sigmas:g} σ_v ≤ {self.standstill_speed_floor_mps:g} m/s (else "
            f"undecidable: flag 256; a stop after {self.quiet_stop_s:g} s of quiet: the travel "
            f"{self.travel_span_m:g} m at the floor speed)",
            f"sensitivity known to {self.sensitivity_std_frac * 100:.3g} % (1σ): carried in the reported σ",
        ] + ([
            "duty-cycle reading's instant in its period not known: up to (S·T2/2g)·∫a² dt of position per move "
            "carried in the reported σ"] if self.duty_cycle_reading_unknown else [])


def quantisation_noise(sensor: SensorParams) -> tuple[float, float, float]:
    """8051 timer quantisation of the duty cycle, in g: (per-sample variance, lag-1 covariance, N²).

    T1 = fall latch − rise latch, T2 = next rise − rise; each latch's rounding is
    uniform over one tick (variance 1/12). With D the duty cycle, the duty error is
    [(1 − D)ε_r − ε_f + D·ε_r'] / T2, and the next sample shares ε_r': variance
    ((1 − D)² + 1 + D²)/12, lag-1 covariance D(1 − D)/12 (ticks²/T2²). Their
    low-frequency density N² = 2Ts·(var + 2 cov) = 2Ts·(2/12)/(T2·S)² — the rounding does
    not telescope, so it integrates like white noise. Evaluated at zero g (D = 0.5).
    """
    t2_ticks = sensor.t2_s * sensor.tick_hz
    scale = 1.0 / (t2_ticks * SENSITIVITY_DUTY_PER_G) ** 2
    d = ZERO_G_DUTY
    var = ((1 - d) ** 2 + 1 + d * d) / 12.0 * scale
    cov1 = d * (1 - d) / 12.0 * scale
    density_sq = 2.0 * sensor.t2_s * (var + 2 * cov1)
    return var, cov1, density_sq


def default_bias_random_walk(white_density: float, record_s: float = 4 * 3600.0) -> float:
    """K when no drift fit is given: the largest random walk a record of record_s showing
    only white noise would have missed — σ_A(τ) = N/√(2τ) at τ = record/4, read as K·√(τ/3)."""
    tau = record_s / 4.0
    return white_density / math.sqrt(2.0 * tau) * math.sqrt(3.0 / tau)


def from_sensor_model(sensor: SensorParams = BOARD_SENSOR, drift_fit: FittedDrift | None = None,
                      axis: str = "x", **overrides) -> EstimatorSettings:
    """Settings for the ADXL202 on the 8051 board.

    - N: data-sheet density (200 µg/√Hz) and the timer quantisation, added in power;
      from a drift fit, the white-noise term of its Allan deviation instead (it sees both).
    - per-sample σ and autocorrelation: the CX filter makes the sensor noise AR(1) with
      a = e^(−2π f Ts) and variance N²·π/2·f (sensor_model.noise_rms_g); plus quantisation.
    - K: the drift fit's rate random walk, or its bound when the record shows none
      (FittedDrift.random_walk_g_per_rts); without a fit, default_bias_random_walk.
    - drift: the fit's C1, T; without a fit, the sensor model's (the paper's assumed) drift.
    """
    period = sensor.t2_s
    q_var, q_cov1, q_density_sq = quantisation_noise(sensor)
    sensor_rms_g = sensor.noise_rms_g
    a = math.exp(-2.0 * math.pi * sensor.bandwidth_hz * period)
    sample_var_g = sensor_rms_g**2 + q_var
    acf = [sensor_rms_g**2 * a**k / sample_var_g for k in range(1, ACF_LAGS + 1)]
    acf[0] += q_cov1 / sample_var_g
    density_g = math.sqrt(sensor.noise_density_g_per_rthz**2 + q_density_sq)
    drift_model = getattr(sensor, axis).drift
    source = "sensor model (data sheet + timer quantisation)"
    if drift_fit is not None:
        drift_model = drift_fit.model
        if drift_fit.white_density_g_per_rthz is not None:
            density_g = drift_fit.white_density_g_per_rthz
        k_g = drift_fit.random_walk_g_per_rts
        source = "sensor model + fitted drift"
    else:
        k_g = default_bias_random_walk(density_g)
    values = dict(
        sample_period_s=period,
        accel_white_density_mps2_per_rthz=density_g * G,
        sample_noise_std_mps2=math.sqrt(sample_var_g) * G,
        noise_autocorrelation=tuple(acf),
        bias_random_walk_mps2_per_rts=k_g * G,
        drift_c1_mps2=drift_model.c1_g * G,
        drift_time_constant_s=drift_model.time_constant_s,
        missing_acc_std_mps2=sensor.range_g * G / math.sqrt(3.0),
        sensor_lag_s=1.0 / (2.0 * math.pi * sensor.bandwidth_hz),
        duty_cycle_reading_unknown=True,
        source=source,
    )
    values.update(overrides)
    return EstimatorSettings(**values)


MIN_REST_SAMPLES = 8
# a sensor without a model: its sensitivity as its data sheet gives it, ±3 % (MPU-6050)
FOREIGN_SENSITIVITY_STD_FRAC = 0.015


def from_rest(acc_rest_mps2, period_s: float, **overrides) -> EstimatorSettings:
    """Settings for a sensor without a model, from a stretch of its own standstill.

    - N: the overlapping Allan deviation of the rest read at τ ≥ 5 periods (past the
      sensor's own filter), median of σ_A·√(2τ); a rest too short for that (fewer than
      two such points: under ~1 s at 100 Hz) gives N from its long-run variance instead,
      2·Ts·σ²·(1 + 2Σρ_k), and says so in `source`;
    - per-sample σ and autocorrelation: the rest's sample statistics;
    - K: what a 4-hour record of this white noise could have missed
      (default_bias_random_walk(N), as for the ADXL without a drift fit). A rest of
      seconds cannot resolve a random walk at all: its bound (2.7 mg/√s from the 4.6 s
      rest of datasets/leiria-robot/eV50p) lets the bias wander 6 mg in a 5 s cruise,
      so the velocity test loses the cruise within seconds and any quiet stretch passes
      as a stop. The bias is taken as stable instead, and what breaks that assumption —
      an offset that steps between stops — is caught by the mean test and flagged
      (estimator_kernel F_OFFSET_STEP, F_UNTRUSTED);
    - no drift model (a short record cannot identify one);
    - the sensitivity known to 1.5 % (1σ): a consumer MEMS part's initial tolerance
      (MPU-6050 data sheet: ±3 %), read as 2σ, as the ADXL's calibration's ±1 % is.
    Raises ValueError for fewer than MIN_REST_SAMPLES finite samples.
    """
    rest = np.asarray(acc_rest_mps2, dtype=float)
    rest = rest[np.isfinite(rest)]
    if rest.size < MIN_REST_SAMPLES:
        raise ValueError(f"a rest of {rest.size} samples is too short to measure the noise "
                         f"(need ≥ {MIN_REST_SAMPLES})")
    sample_std = float(np.std(rest))
    if sample_std == 0.0:
        raise ValueError("the rest is constant: no noise to measure (a quantised or synthetic signal?)")
    lags = min(ACF_LAGS, rest.size - 1)
    acf = np.zeros(ACF_LAGS)
    acf[:lags] = autocorrelation(rest, lags)[1:]
    allan = allan_deviation(rest, period_s)
    usable = (allan.tau_s >= 5 * period_s) & (allan.tau_s <= rest.size * period_s / 4.0) & (allan.adev > 0)
    how = f"recording's own rest ({rest.size} samples, {rest.size * period_s:.2f} s)"
    if np.count_nonzero(usable) >= 2:
        density = float(np.median(allan.adev[usable] * np.sqrt(2.0 * allan.tau_s[usable])))
    else:
        # long-run variance: the low-frequency level that integration sees
        window = min(lags, max(1, rest.size // 4))
        gain = max(1.0 + 2.0 * float(np.sum(acf[:window])), 1.0)
        density = sample_std * math.sqrt(2.0 * period_s * gain)
        how += "; too short for an Allan deviation: N from its long-run variance"
    values = dict(
        sample_period_s=period_s,
        accel_white_density_mps2_per_rthz=density,
        sample_noise_std_mps2=sample_std,
        noise_autocorrelation=tuple(float(v) for v in acf),
        bias_random_walk_mps2_per_rts=default_bias_random_walk(density),
        sensitivity_std_frac=FOREIGN_SENSITIVITY_STD_FRAC,
        source=how,
    )
    values.update(overrides)
    return EstimatorSettings(**values)
