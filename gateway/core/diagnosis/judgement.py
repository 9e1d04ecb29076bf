"""When a significant effect is named: the ranges and thresholds, and cross-validation.

With thousands of samples any small mismatch between the recording and the baseline
gives a large ΔBIC, so significance alone names whatever fits best. An effect is named
only when it is also

- **outside the setup's own range** (``SETUP_RANGES``): what every real setup has and
  the data sheet leaves open — the calibration's residual sensitivity error, where in
  its period a sample reads (the timing convention) and the output filter's spread with
  its capacitor. Inside that range the fitted value is kept in the model and reported
  as a measured property of the setup, not as an effect;
- **physically possible** (``physical``): outside that range the report says "something
  of this shape, not physical as X — look elsewhere";
- **predictive**: fitted on one half of the record it must improve the likelihood of
  the other half, both ways (``cross_validated``);
- **of a size that matters**: it explains at least MIN_RESIDUAL_SHARE of the residual
  variance or improves the distance error by at least MIN_DISTANCE_GAIN_MM, and does
  not worsen it by more than MAX_DISTANCE_LOSS_MM. Smaller ones are "negligible";
- **still needed once the others are in** (the backward pass in selection.py).
"""
from __future__ import annotations

import math

import numpy as np

from gateway.core.diagnosis.context import G, Prepared
from gateway.core.sensor_model import CALIBRATED_SENSITIVITY_TOLERANCE_FRAC

SENSITIVITY_TOLERANCE_FRAC = CALIBRATED_SENSITIVITY_TOLERANCE_FRAC
# a fitted value is outside the setup's range only when it is so by this many of its
# standard errors (2σ: one-sided 2 %)
SETUP_SIGMAS = 2.0
# the output filter's capacitor: ±20 % (X7R ceramics are sold at ±10–20 %)
CAPACITOR_TOLERANCE_FRAC = 0.20
# where inside its period a sample reads: a period-mean convention against an edge or
# a point sample differs by up to half a period; one period is allowed
TIME_CONVENTION_PERIODS = 1.0
# (the command's) a coarse reference is compared over this many of its own intervals;
# interpolated between its samples it is off by up to half an interval
REFERENCE_INTERVALS_PER_BLOCK = 4

# a USB adapter's latency timer is set in whole ms (1–255, default 16); a hold-back
# under 2 ms is what an ordinary serial link's jitter (a few tenths of a ms) fits as
ORDINARY_HOLD_BACK_S = 2e-3

# "matters": the share of the baseline's residual variance, or the distance error
MIN_RESIDUAL_SHARE = 0.01
MIN_DISTANCE_GAIN_MM = 0.5
MAX_DISTANCE_LOSS_MM = 0.5
# ...a loss counts only when the other errors at the stops cannot have made it by chance
# (distance_loss_is_chance): the cross term's 2σ, one-sided 2 %
DISTANCE_CHANCE_SIGMAS = 2.0

# physically possible values (data sheets of the ADXL202 family, mounts, boards)
MAX_SCALE_ERROR_FRAC = 0.20  # sensitivity 10–15 %/g around 12.5 %/g
MAX_QUADRATIC_PER_G = 0.03  # data sheet: ~0.2 % of full scale; 3 %/g is far beyond any part
MAX_DAMPING_RATIO = 0.5  # above, a "resonance" does not ring: it is a filter shape
MIN_BANDWIDTH_HZ = 2.0  # a mount or CX low-pass below 2 Hz would swallow the motion itself
MAX_DELAY_S = 0.25  # a reference logged more than ¼ s off is a clock problem, not a lag
MAX_TILT_RAD_PER_M = 0.5  # 29°/m: a rail or an arm turning the sensor that much
MAX_OFFSET_MG_PER_C = 10.0  # data sheet: order of mg/°C
MAX_CROSS_GAIN = 0.15  # ±2 % cross-axis sensitivity + a few degrees of misalignment
# host timing: a USB adapter's latency timer is at most 255 ms; a clock, even an RC
# oscillator (±2 %), is not tens of per cent off. Beyond: a logger's backlog or a host
# that fell behind — host times that are wrong, but not by a clock or a latency timer
MAX_HOLD_BACK_S = 0.255
MAX_CLOCK_RATE_ERROR = 0.02


def period_s(prep: Prepared) -> float:
    return prep.data.period_s


def setup_range(name: str, prep: Prepared, theta: np.ndarray, std: np.ndarray | None = None) -> str | None:
    """If the fitted value lies inside what the setup itself allows: its description.
    theta: the effect's fitted parameters (timing: the hold-back in seconds); std their
    standard errors, where known — a value within SETUP_SIGMAS of the range is not shown
    to lie outside it (a part at the edge of its tolerance reads either side of it)."""
    margin = SETUP_SIGMAS * float(std[0]) if std is not None and np.isfinite(std[0]) else 0.0
    if name == "scale_factor" and abs(theta[0]) - margin <= SENSITIVITY_TOLERANCE_FRAC:
        return (f"sensitivity {100 * theta[0]:+.2f} %: within the calibration's "
                f"±{100 * SENSITIVITY_TOLERANCE_FRAC:g} %" + (" (at 2σ of its estimate)" if
                                                             abs(theta[0]) > SENSITIVITY_TOLERANCE_FRAC else ""))
    # a coarse reference interpolated between its own samples is also off by up to half its interval
    allowed_delay = (TIME_CONVENTION_PERIODS + 0.5 * (prep.block - 1) / REFERENCE_INTERVALS_PER_BLOCK) * period_s(prep)
    if name == "reference_delay" and abs(theta[0]) <= allowed_delay:
        return (f"reference timing {1e3 * theta[0]:+.2f} ms: within {1e3 * allowed_delay:.1f} ms (where in its "
                "period a sample reads" + (", half the reference's own interval" if prep.block > 1 else "") + ")")
    if name == "output_filter":  # fitted only inside the capacitor's tolerance (signal_effects.OutputFilter)
        bw = prep.data.sensor_bandwidth_hz
        return (f"output filter at {theta[0]:.1f} Hz: the nominal {bw:.1f} Hz within its capacitor's "
                f"±{100 * CAPACITOR_TOLERANCE_FRAC:g} %")
    if name == "reading_instant":  # fitted only between the two readings (signal_effects.ReadingInstant)
        return (f"duty-cycle reading {theta[0]:.2f} of the way from the period's mean (0) to where the "
                "duty cycle ends (1)")
    if name == "timing" and theta[0] < ORDINARY_HOLD_BACK_S:
        return (f"host arrival jitter fitted as a hold-back of {1e3 * theta[0]:.2f} ms: an ordinary link's "
                f"jitter (below {1e3 * ORDINARY_HOLD_BACK_S:g} ms)")
    if name == "bandwidth":
        # an extra pole's lag 1/(2π fc) within the capacitor's spread of the sensor's own
        # pole plus half a period of timing convention
        bw = prep.data.sensor_bandwidth_hz
        own_lag = (CAPACITOR_TOLERANCE_FRAC / (2 * math.pi * bw)) if bw else 0.0
        allowed = own_lag + 0.5 * period_s(prep)
        lag = 1.0 / (2 * math.pi * theta[0])
        if lag <= allowed:
            return (f"extra lag {1e3 * lag:.2f} ms (pole at {theta[0]:.0f} Hz): within the output filter's "
                    f"capacitor tolerance and the timing convention ({1e3 * allowed:.2f} ms)")
    return None


def physical(name: str, prep: Prepared, theta: np.ndarray) -> str | None:
    """None when the fitted parameters are physically possible, else why not."""
    if name == "scale_factor" and abs(theta[0]) > MAX_SCALE_ERROR_FRAC:
        return f"a sensitivity error of {100 * theta[0]:+.0f} % (data sheet: within ±20 %)"
    if name == "nonlinearity" and abs(theta[0]) > MAX_QUADRATIC_PER_G:
        return f"a quadratic term of {100 * theta[0]:+.1f} %/g (data sheet: ~0.2 % of full scale)"
    if name == "vibration":
        f, z = theta
        if z > MAX_DAMPING_RATIO:
            return f"a resonance at {f:.0f} Hz with damping ratio {z:.2f} (> {MAX_DAMPING_RATIO:g}: it would not ring)"
        bw = prep.data.sensor_bandwidth_hz
        if bw and f > 3.0 * bw:
            return f"a resonance at {f:.0f} Hz, far above the sensor's {bw:.0f} Hz bandwidth"
    if name == "bandwidth" and theta[0] < MIN_BANDWIDTH_HZ:
        return (f"a low-pass at {theta[0]:.2f} Hz: it would swallow the motion itself "
                "(a reference without detail above a few Hz fits this shape)")
    if name == "reference_delay" and abs(theta[0]) > MAX_DELAY_S:
        return f"a reference {1e3 * theta[0]:+.0f} ms off (beyond ±{1e3 * MAX_DELAY_S:g} ms: a clock problem)"
    if name == "tilt" and abs(theta[0]) > MAX_TILT_RAD_PER_M:
        return f"a tilt gradient of {math.degrees(theta[0]):.0f}°/m"
    if name == "temperature_offset" and abs(theta[0] / G * 1e3) > MAX_OFFSET_MG_PER_C:
        return f"{theta[0] / G * 1e3:.1f} mg/°C (data sheet: order of 1 mg/°C)"
    if name == "timing":  # theta: (hold-back s, clock rate error as a fraction)
        hold, rate = theta
        if hold > MAX_HOLD_BACK_S or abs(rate) > MAX_CLOCK_RATE_ERROR:
            return (f"host times held back up to {1e3 * hold:.0f} ms with a clock {1e6 * rate:+.0f} ppm off "
                    f"(a latency timer is at most {1e3 * MAX_HOLD_BACK_S:g} ms, a clock within "
                    f"±{100 * MAX_CLOCK_RATE_ERROR:g} %): a logger's backlog or a host that fell behind, "
                    "not a clock or a latency timer")
    return None


def halves(prep: Prepared) -> tuple[np.ndarray, np.ndarray]:
    """The record's first and second half in time, over the fit mask."""
    t = prep.data.t_s
    mid = 0.5 * (t[0] + t[-1])
    first = prep.fit_mask & (t < mid)
    return first, prep.fit_mask & ~first


def residual_share(rms_before: float, rms_after: float) -> float:
    """The share of the residual variance an effect explains."""
    if not (rms_before > 0):
        return 0.0
    return 1.0 - (rms_after / rms_before) ** 2


def distance_loss_is_chance(distance: dict) -> bool:
    """True when a distance "loss" is what the other errors at the stops make by chance.

    Before the compensation the stop errors are b = e + c (e: every other error, c: the
    effect's share), after it a = e if the effect is real and rightly compensated. Then
    mean(b²) − mean(a²) = mean(c²) + 2·mean(a·c): removing a real effect whose share
    happened to cancel the other errors at a handful of stops raises the RMS, by a cross
    term mean(a·c) that is zero on average with a standard error √Σ(a·c)²/n. A
    compensation that moves the estimate away from the reference (a shape fitted to a
    mismatch: c = −d, a = b + d) makes that term −mean(d²) and more, far beyond its
    chance. So a loss counts only where the cross term is below −DISTANCE_CHANCE_SIGMAS
    of its standard error. Found on the simulator: a temperature term fitted within 5 %
    whose compensation gave the clean twin's stop errors within 0.1 mm, "worse by
    0.62 mm" (docs/diagnosis.md §7, the noise model per rest)."""
    before, after = distance.get("before", {}), distance.get("after", {})
    if distance.get("metric") != "stop_rms_mm" or "stops_mm" not in before or "stops_mm" not in after:
        return False
    b, a = np.asarray(before["stops_mm"], float), np.asarray(after["stops_mm"], float)
    if a.size != b.size or a.size < 2:
        return False
    cross = a * (b - a)
    standard_error = float(np.sqrt(np.sum(cross**2))) / a.size
    return bool(float(np.mean(cross)) >= -DISTANCE_CHANCE_SIGMAS * standard_error)


def matters(share: float | None, distance_mm: float | None,
            position_mm: float | None = None, loss_is_chance: bool = False) -> tuple[bool, str]:
    """(named, why) from the residual share, the distance improvement and, for an effect
    a user meets elsewhere than in the distance (host timestamps: position_mm, see
    side_effects.host_time_position_mm), the position error it makes there (None: unknown).
    loss_is_chance: a distance loss that the other errors at the stops explain
    (distance_loss_is_chance) does not count against the effect."""
    if distance_mm is not None and distance_mm < -MAX_DISTANCE_LOSS_MM and not loss_is_chance:
        return False, f"makes the distance error worse by {-distance_mm:.2f} mm"
    if share is not None and share >= MIN_RESIDUAL_SHARE:
        return True, ""
    if distance_mm is not None and distance_mm >= MIN_DISTANCE_GAIN_MM:
        return True, ""
    if position_mm is not None and position_mm >= MIN_DISTANCE_GAIN_MM:
        return True, ""
    size = []
    if share is not None:
        size.append(f"explains {100 * share:.2f} % of the residual variance")
    if distance_mm is not None:
        size.append(f"distance {distance_mm:+.2f} mm")
    if position_mm is not None:
        size.append(f"a host-timed position off by {position_mm:.2f} mm at top speed")
    return False, "; ".join(size) or "no measurable gain"
