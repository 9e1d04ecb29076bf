"""Effects on the measured axis that the baseline sensor model lacks, each a small model extension.

A signal effect changes what the model predicts for every sample. The prediction is
built in stages, in physical order:

    0 reference  the reference itself is off (reference_delay)
    1 filter     the motion reaches the sensing element changed (vibration, bandwidth)
    2 sensor     the element reads it with an extra term (scale_factor, nonlinearity,
                 tilt, temperature_offset)
    3 output     the electronics limit it (clipping)

Each effect gives starting values from the current residual (a grid or a linear fit:
the joint non-linear fit then only polishes them), bounds, and how the estimator can
use it (`compensate`): the measured acceleration corrected, or a setting changed.
Parameters are fitted in SI units; `report` turns them into the units people quote.
The interface they implement and the model state they change: signal_interface.py.
"""
from __future__ import annotations

import math

import numpy as np

from gateway.core.diagnosis.context import MIN_TEMPERATURE_STD_C, USABLE_COLUMN_FRACTION, G
from gateway.core.diagnosis.judgement import CAPACITOR_TOLERANCE_FRAC, MAX_DIE_LAG_S
from gateway.core.diagnosis.reading import shifted
from gateway.core.diagnosis.signal_interface import (
    Compensation,
    SignalEffect,
    _grid_best,
    _grid_with_free_gains,
    _ls_coefficient,
)
from gateway.core.filters import mount_resonance, moved_pole, one_pole_lowpass
from gateway.core.model_compensation import compensate_term, die_temperature_c, other_axis_motion
from gateway.core.sensor_model import edge_reading_excess_mps2


class ScaleFactor(SignalEffect):
    name = "scale_factor"
    summary = "sensitivity differs from the calibration: reads (1 + s)·a"
    param_names = ("scale_error_frac",)

    def initial(self, prep, residual, sig):
        return np.array([_ls_coefficient(residual, sig.reading, prep.fit_mask)])

    def bounds(self, prep):
        return [-0.5], [0.5]

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * sig.reading

    def compensate(self, prep, theta, acc, est):
        return Compensation(acc_mps2=compensate_term(self.name, self.model_params(prep, theta), acc, est))

    def full_scale_gain(self, theta):
        # the part saturates in acceleration, at its range; the reading of that saturation
        # passes through the sensitivity like any other (a part 0.7 % low reads its ±2 g as
        # ±1.986 g: left to the baseline's ±2 g, "clipping" fitted there)
        return 1.0 + float(theta[0])


class Nonlinearity(SignalEffect):
    name = "nonlinearity"
    summary = "a quadratic term: reads a + β·a²/g (data sheet: ~0.2 % of full scale)"
    param_names = ("quadratic_per_g",)

    def initial(self, prep, residual, sig):
        return np.array([_ls_coefficient(residual, sig.reading**2 / G, prep.fit_mask)])

    def bounds(self, prep):
        return [-0.5], [0.5]

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * sig.reading**2 / G

    def compensate(self, prep, theta, acc, est):
        # first-order inverse of a + βa²/g, on the motion as the model has it: the reading
        # less its level at rest. Squared with the level in, a 0.1 g offset adds 2β·0.1 g·a,
        # a sensitivity change the model gave to the scale factor (fitted beside it and
        # compensated there): removed twice, 0.3 % of the distance at β = 1.5 %/g
        motion = acc - prep.level_at_rest(acc)
        return Compensation(acc_mps2=acc - theta[0] * motion**2 / G)


class Tilt(SignalEffect):
    """Gravity leaking into the axis as the tilt varies along the path.

    A constant tilt θ adds g·sin θ: indistinguishable from the zero-g offset, and removed
    with it. What the baseline misses is a tilt that changes with position — a rail that
    is not level, an arm or a hand that turns the sensor as it moves: g·κ·x to first
    order, κ in rad/m. Without a recorded reference, x is the smoothed estimate's
    position (so the compensation feeds the estimate back, once).
    """

    name = "tilt"
    summary = "gravity leaking into the axis as the tilt varies along the path: g·κ·x"
    param_names = ("tilt_gradient_rad_per_m",)
    uses_position = True  # gain.py iterates the correction with the estimate's position

    def unusable(self, prep):
        return None if prep.data.ref_pos_m is not None else "needs a position: the reference or an estimate"

    def initial(self, prep, residual, sig):
        return np.array([_ls_coefficient(residual, G * sig.pos_m, prep.fit_mask)])

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * G * sig.pos_m

    def report(self, theta, std):
        return {"tilt_coefficient": (float(theta[0]), float(std[0])),
                "tilt_gradient_deg_per_m": (math.degrees(float(theta[0])), math.degrees(float(std[0])))}

    def compensate(self, prep, theta, acc, est):
        return Compensation(acc_mps2=compensate_term(self.name, {"tilt_gradient_rad_per_m": float(theta[0])}, acc, est),
                            note="position from the estimate, iterated until it settles")


class TemperatureOffset(SignalEffect):
    """The zero-g offset moves with the die's temperature: k·(T_die − T̄_die).

    The board's thermometer is not the accelerometer's die. Heat from the drive reaches
    the die through the board and the package, so the die's temperature follows the
    thermometer's through a thermal lag: first order, T_die = T through 1/(1 + sτ)
    (model_compensation.die_temperature_c, the one place the lag is computed, for the
    fit and the compensation alike). τ is fitted within the package's physical range
    0 … judgement.MAX_DIE_LAG_S (0: the die at the thermometer's temperature), so the
    candidate has two parameters and the criterion counts both. Fitted without its lag,
    a heating that follows the machine's duty leaves a residual that follows the strokes,
    and an offset growing with travel (tilt) takes it."""

    name = "temperature_offset"
    summary = ("zero-g offset moves with the die's temperature: k·(T_die − T̄), the die lagging the board's "
               "thermometer by τ (data sheet: mg/°C)")
    param_names = ("offset_mps2_per_c", "die_lag_s")
    # the starting grid of the lag (the joint fit then polishes it within the bounds):
    # 0 and geometric steps of ~1.6× up to the range's top
    LAG_GRID_S = (0.0, *np.geomspace(0.25, MAX_DIE_LAG_S, 10))

    def unusable(self, prep):
        if not prep.data.column_ok("temp_c", min_std=MIN_TEMPERATURE_STD_C):
            return "needs a temperature column that varies (temp_c)"
        return None

    @staticmethod
    def _die_temperature(prep, lag_s):
        return die_temperature_c(prep.data.t_s, prep.data.temperature_c, float(lag_s))

    def _regressor(self, prep, lag_s):
        temp = self._die_temperature(prep, lag_s)  # the reports' staircase made smooth, lagged
        fill = float(np.nanmean(temp))
        return np.nan_to_num(temp, nan=fill) - fill

    def initial(self, prep, residual, sig):
        """The lag on a grid; at each, the coefficient by least squares on the residual."""
        best = _grid_with_free_gains(prep, residual, [(lag,) for lag in self.LAG_GRID_S],
                                     lambda point: [self._regressor(prep, point[0])])
        if best is None:
            return np.array([0.0, 0.0])
        (lag,), (k,) = best
        return np.array([k, lag])

    def bounds(self, prep):
        # the coefficient free (a fit beyond the part's range is reported as not
        # physical); the lag within its physical range, the fit held at its ends
        return [-np.inf, 0.0], [np.inf, MAX_DIE_LAG_S]

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * self._regressor(prep, theta[1])

    def report(self, theta, std):
        return {"offset_mg_per_c": (float(theta[0] / G * 1e3), float(std[0] / G * 1e3)),
                "die_lag_s": (float(theta[1]), float(std[1]))}

    def model_params(self, prep, theta):
        die = self._die_temperature(prep, theta[1])
        return {"offset_mps2_per_c": float(theta[0]), "die_lag_s": float(theta[1]),
                "reference_c": float(np.nanmean(die))}

    def compensate(self, prep, theta, acc, est):
        return Compensation(acc_mps2=compensate_term(self.name, self.model_params(prep, theta), acc, est))


class Vibration(SignalEffect):
    """A resonance that rings at its own frequency f0 with damping ζ.

    A sensor on a flexible mount follows its base through the mount's transfer function
    (gateway/core/filters.mount_resonance): the ringing after each change of
    acceleration is r = mount(a) − a. What excites it is not always that step alone (a
    motor, a shaker, a second mode in the machine), so amplitude and phase are free:
    the model adds g·r + q·ṙ/(2π f0) (g = 1, q = 0: the mount's own response). Physical
    range: |g + i·q| no larger than the resonance's own amplification 1/(2ζ) (a
    second-order system's peak transmissibility), ζ ≤ MAX_DAMPING_RATIO (above, it does
    not ring: a filter shape, the `bandwidth` effect's)."""

    name = "vibration"
    stage = 1
    summary = "a resonance rings at f0 with damping ζ, amplitude and phase free (gain, quadrature)"
    param_names = ("frequency_hz", "damping_ratio", "gain", "quadrature")

    def _nyquist(self, prep):
        return 0.5 / prep.data.period_s

    @staticmethod
    def _ringing(prep, full, f, z):
        ring = mount_resonance(full, prep.data.period_s, f, z) - full
        return ring, np.gradient(ring) / (2.0 * math.pi * f * prep.data.period_s)

    def initial(self, prep, residual, sig):
        """A grid over (f0, ζ); at each, gain and quadrature by least squares on the residual."""
        top = min(0.8 * self._nyquist(prep), 400.0)
        grid = [(f, z) for f in np.geomspace(2.0, top, 36) for z in (0.02, 0.05, 0.12, 0.3)]
        best = _grid_with_free_gains(prep, residual, grid, lambda point: [
            r[prep.where] for r in self._ringing(prep, sig.full, *point)])
        if best is None:
            return np.array([2.0, 0.05, 1.0, 0.0])
        (f, z), (gain, quad) = best
        return np.array([f, z, gain, quad])

    def bounds(self, prep):
        # the fit's search range, wider than the physical range (judgement.physical) so
        # that a shape fitted outside it is seen and reported as not physical
        return [0.5, 0.003, -100.0, -100.0], [0.9 * self._nyquist(prep), 0.9, 100.0, 100.0]

    def apply(self, prep, theta, sig):
        f, z, gain, quad = theta
        ring, dring = self._ringing(prep, sig.full, f, z)
        sig.full = sig.full + gain * ring + quad * dring

    def compensate(self, prep, theta, acc, est):
        return Compensation(note="not compensated: the ringing integrates to zero velocity and position change")


class Bandwidth(SignalEffect):
    name = "bandwidth"
    stage = 1
    summary = "a low-pass the model lacks (mount, a larger CX, the board's own filter): one pole at fc"
    param_names = ("cutoff_hz",)

    def initial(self, prep, residual, sig):
        top = 0.9 * 0.5 / prep.data.period_s
        return _grid_best(prep, residual, sig, self, [(f,) for f in np.geomspace(0.5, top, 40)])

    def bounds(self, prep):
        # search range: below the physical 2 Hz (judgement.MIN_BANDWIDTH_HZ) so that such a
        # fit is reported as not physical; above, up to the sampling's Nyquist frequency
        return [0.2], [0.95 * 0.5 / prep.data.period_s]

    def apply(self, prep, theta, sig):
        sig.full = one_pole_lowpass(sig.full, prep.data.period_s, theta[0])

    def compensate(self, prep, theta, acc, est):
        # the estimator undoes a sensor lag τ in its outputs; the extra pole adds its own
        return Compensation(settings={"extra_sensor_lag_s": 1.0 / (2.0 * math.pi * theta[0])})


class PartProperty(SignalEffect):
    """A property of the known duty-cycle part that the data sheet leaves open: fitted only
    inside its range, always a measured property of the setup, never named. A recording
    of another sensor does not say what its own filter is: not fitted there."""

    setup_only = True

    def unusable(self, prep):
        bw = prep.data.sensor_bandwidth_hz
        if not bw or not np.isfinite(bw):
            return "not the known duty-cycle part: its own filter is not known"
        return super().unusable(prep)


class OutputFilter(PartProperty):
    """Not an effect: the part's own output filter, f−3dB = 1/(2π·32 kΩ·CX), at the value
    its capacitor really has. The baseline takes the nominal CX; a board's capacitor is
    within a tolerance (judgement.CAPACITOR_TOLERANCE_FRAC), and a part at another value
    reads each edge of the motion earlier or later by Δτ — which short acceleration
    phases turn into what looks like a sensitivity error of Δτ/T_acc, and which spoils
    the cross-validation of everything else (on the simulator with parts within ±10 %:
    a temperature swing missed in 6 of 20 cases, `scale_factor` named beside it). Fitted
    only within the tolerance, so it is always a measured property of the setup (never
    named); a slower filter than that is the `bandwidth` effect's."""

    name = "output_filter"
    stage = 1
    summary = "the part's own output filter at its capacitor's real value (a property of the setup)"
    param_names = ("bandwidth_hz",)

    def bounds(self, prep):
        bw = prep.data.sensor_bandwidth_hz
        top = min(bw / (1.0 - CAPACITOR_TOLERANCE_FRAC), 0.95 * 0.5 / prep.data.period_s)
        return [bw / (1.0 + CAPACITOR_TOLERANCE_FRAC)], [top]

    def initial(self, prep, residual, sig):
        lo, hi = self.bounds(prep)
        return _grid_best(prep, residual, sig, self, [(f,) for f in np.linspace(lo[0], hi[0], 9)])

    def apply(self, prep, theta, sig):
        sig.full = moved_pole(sig.full, prep.data.period_s, prep.data.sensor_bandwidth_hz, theta[0])

    def compensate(self, prep, theta, acc, est):
        # the estimator undoes the nominal lag; the part's own differs by this much (either sign)
        nominal = 1.0 / (2.0 * math.pi * prep.data.sensor_bandwidth_hz)
        return Compensation(settings={"extra_sensor_lag_s": 1.0 / (2.0 * math.pi * theta[0]) - nominal})


class ReadingInstant(PartProperty):
    """Not an effect: where in its period the part's modulator reads the signal — over the
    period (its mean: the baseline's convention) or where the duty cycle ends (natural
    sampling; the data sheet does not say which). Read at the edge, a sample comes S·T2·a/g
    after the period's middle: the reading is a + (S·T2/2g)·d(a²)/dt, which leaves
    (S·T2/2g)·∫a² dt of position per move (docs/estimation.md §Never confidently wrong).
    Fitted as the fraction of the way from the mean (0) to the edge (1), only within that
    range, so it is always a measured property of the setup (never named); told to the
    estimator, it corrects the measurement."""

    name = "reading_instant"
    stage = 2
    summary = "where in its period the modulator reads the signal: mean (0) … edge (1) (a property of the setup)"
    param_names = ("edge_fraction",)

    @staticmethod
    def _edge_term(prep, full):
        """What an edge reading adds, on the received samples, to the model's reading of the motion."""
        period = prep.data.period_s
        return edge_reading_excess_mps2(full, period, period)[prep.where]

    def bounds(self, prep):
        return [0.0], [1.0]

    def initial(self, prep, residual, sig):
        fraction = _ls_coefficient(residual, self._edge_term(prep, sig.full), prep.fit_mask)
        return np.array([min(max(fraction, 0.0), 1.0)])

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * self._edge_term(prep, sig.full)

    def compensate(self, prep, theta, acc, est):
        # the measured motion (its offset taken out: the offset's share is a constant
        # delay, which moves no stop) read back to the period's middle
        finite = np.isfinite(acc)
        motion = np.where(finite, acc - np.median(acc[finite]), 0.0)
        return Compensation(acc_mps2=acc - theta[0] * edge_reading_excess_mps2(motion, prep.data.t_s,
                                                                             prep.data.period_s))


CLIP_TOLERANCE_G = 0.003  # the timer's quantisation: clipped samples scatter by ~1 mg
CLIP_MIN_SAMPLES = 10  # 20 ms of saturation at 500 samples/s


class Clipping(SignalEffect):
    name = "clipping"
    stage = 3
    summary = "the reading saturates below the model's ±2 g range (the part, its supply, the timer)"
    param_names = ("upper_mps2", "lower_mps2")

    # the smoothed estimate follows a clipped reading, so only a recorded reference shows it
    def _limits(self, prep):
        # a foreign sensor may read beyond the ADXL202's range: "no clipping" must fit
        acc = prep.data.acc_mps2[prep.data.valid]
        r = prep.data.range_mps2
        return max(r, 1.01 * float(acc.max())), min(-r, 1.01 * float(acc.min()))

    def initial(self, prep, residual, sig):
        acc = prep.data.acc_mps2[prep.data.valid]
        return np.array([float(acc.max()), float(acc.min())])

    def bounds(self, prep):
        hi, lo = self._limits(prep)
        return [0.0, lo], [hi, 0.0]

    def apply(self, prep, theta, sig):
        sig.out = np.clip(sig.out, theta[1], theta[0])

    def report(self, theta, std):
        return {"upper_g": (float(theta[0] / G), float(std[0] / G)),
                "lower_g": (float(theta[1] / G), float(std[1] / G))}

    def implausible(self, prep, theta) -> str | None:
        """A part that clips reads its limit, again and again: a fit whose limits no run
        of samples sits at is trimming a model's overshoot, not finding saturation."""
        # samples at rest read the offset (1 g on a vertical axis): a limit there clips
        # nothing the motion did, so only moving samples count
        moving = prep.data.valid & ~prep.rest
        acc = prep.data.acc_mps2[moving]
        tol = CLIP_TOLERANCE_G * G
        at_limit = int(np.count_nonzero(np.abs(acc - theta[0]) < tol) + np.count_nonzero(np.abs(acc - theta[1]) < tol))
        if at_limit < CLIP_MIN_SAMPLES:
            return f"only {at_limit} moving samples within {CLIP_TOLERANCE_G * 1e3:g} mg of the fitted limits"
        rest = prep.data.acc_mps2[prep.data.valid & prep.rest]
        if rest.size and not (theta[1] < float(rest.min()) and float(rest.max()) < theta[0]):
            return "the fitted limits cut into the readings at rest"
        return None

    def compensate(self, prep, theta, acc, est):
        # what was clipped is gone: treating those samples as missing loses even the part
        # that was read (measured: −150 mm median), so the estimator is left as it is
        return Compensation(note="not compensated: clipped acceleration cannot be recovered")


class ReferenceDelay(SignalEffect):
    name = "reference_delay"
    stage = 0
    summary = "the reference lags (+) or leads (−) the sensor: the motion at t is the reference at t + d"
    param_names = ("delay_s",)

    def initial(self, prep, residual, sig):
        p = prep.data.period_s
        grid = [(d,) for d in np.arange(-25, 25.5, 0.5) * p]
        return _grid_best(prep, residual, sig, self, grid)

    def bounds(self, prep):
        return [-0.5], [0.5]

    def apply(self, prep, theta, sig):
        # read the reference d later and make the baseline's reading of it anew: exact for
        # a piecewise-constant acceleration, where shifting the reading itself is not
        d = prep.data
        sig.full = prep.delayed_reading(theta[0])
        if sig.pos_m is not None:
            sig.pos_m = shifted(d.t_s, sig.pos_m, theta[0])

    def report(self, theta, std):
        return {"delay_ms": (float(theta[0] * 1e3), float(std[0] * 1e3))}

    def compensate(self, prep, theta, acc, est):
        return Compensation(ref_shift_s=float(theta[0]), note="the error is taken against the shifted reference")


class MotionOffset(SignalEffect):
    """An offset that appears while the axis moves and goes when it stops: b·[moving].

    Physical causes that read this way (one record cannot tell them apart): the carriage
    or tool tilting under its drive's load (g·sin δ: a compliant arm or gearbox deflects
    while the joint's friction torque acts, which the robot's encoders do not see); the
    sensor's vibration rectification (a nonlinear part turns the machine's vibration in
    motion into a level); a motor's field on the part. On a single move at steady speed
    it cannot be told from an offset growing with travel (tilt) — a return stroke would
    separate them (it reverses x, not [moving]). Physical range: |b| ≤ g·sin 5° — a drive
    that tilts its tool by more than 5° is a machine out of order, not a sensor's error.
    Moving: the reference's velocity or acceleration not zero; the compensation uses the
    estimate's own standstill flags."""

    name = "motion_offset"
    summary = "an offset while the axis moves (a tool tilting under its drive, vibration rectification): b·[moving]"
    param_names = ("offset_mps2",)
    uses_position = True  # corrected with the estimate's own motion flags, iterated (gain.py)

    @staticmethod
    def _moving(prep):
        d = prep.data
        return ((np.abs(d.ref_vel_mps) >= 1e-6) | (np.abs(d.ref_acc_mps2) >= 1e-9)).astype(float)

    def initial(self, prep, residual, sig):
        return np.array([_ls_coefficient(residual, self._moving(prep), prep.fit_mask)])

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * self._moving(prep)

    def report(self, theta, std):
        return {"offset_mg": (float(theta[0] / G * 1e3), float(std[0] / G * 1e3)),
                "tilt_in_motion_deg": (math.degrees(math.asin(max(-1.0, min(1.0, theta[0] / G)))),
                                       math.degrees(float(std[0]) / G))}

    def compensate(self, prep, theta, acc, est):
        return Compensation(acc_mps2=compensate_term(self.name, self.model_params(prep, theta), acc, est),
                            note="motion from the estimate's standstill flags, iterated until it settles")


class CrossTalk(SignalEffect):
    """The other axis's own motion leaking into this one: c·(other − its level at rest).

    In-plane misalignment (sin of the angle) plus the part's cross-axis sensitivity
    (data sheet: ±2 %); physical range |c| ≤ judgement.MAX_CROSS_GAIN. The other axis is
    taken as measured (it has no reference): what it reads of its own motion is what
    leaks. When the user says it stands (--other-axis-still) it has no motion of its own
    — what it reads is this axis's motion (the `cross_axis` side effect) and a
    regression on it would read this axis's own scale back: not looked for then."""

    name = "cross_talk"
    summary = "the other axis's measured motion leaks into this one: c·(other − level at rest)"
    param_names = ("gain",)

    def unusable(self, prep):
        d = prep.data
        if d.other_mps2 is None or np.isfinite(d.other_mps2).mean() < USABLE_COLUMN_FRACTION:
            return "needs the other axis"
        if d.other_axis_still:
            return "the other axis stands still (--other-axis-still): it has no motion of its own to leak"
        return super().unusable(prep)

    @staticmethod
    def _regressor(prep):
        return other_axis_motion(prep.data.other_mps2, prep.rest)

    def initial(self, prep, residual, sig):
        return np.array([_ls_coefficient(residual, self._regressor(prep), prep.fit_mask)])

    def apply(self, prep, theta, sig):
        sig.out = sig.out + theta[0] * self._regressor(prep)

    def compensate(self, prep, theta, acc, est):
        return Compensation(acc_mps2=compensate_term(self.name, self.model_params(prep, theta), acc, est))


SIGNAL_EFFECTS: tuple[SignalEffect, ...] = (
    ScaleFactor(), Tilt(), TemperatureOffset(), Vibration(), Bandwidth(), Nonlinearity(),
    Clipping(), ReferenceDelay(), MotionOffset(), CrossTalk(), OutputFilter(), ReadingInstant(),
)
