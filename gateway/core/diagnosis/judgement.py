"""When a predictive effect is named: the setup's ranges, the physical ranges, the distance.

Every candidate is first judged by the one criterion (criterion.py: out-of-block
predictive likelihood at the false-alarm rate ALPHA). A predictive effect is then

- **the setup's own property** when its value lies inside what every real setup has and
  the data sheet leaves open (``setup_range``: the calibration's residual sensitivity
  error, where in its period a sample reads, the output filter's spread with its
  capacitor): kept in the model, reported as measured, not named;
- **not physical** outside what a part, mount or machine can have (``physical``): the
  report says "something of this shape, not physical as X — look elsewhere";
- **named**, unless its compensation makes the distance worse beyond the interval of a
  bootstrap over the stops (``matters``: a loss counts at any number of stops), or what
  is left unexplained in the residual is larger than it (selection.leftover_structure).
The backward pass (selection.py) then drops any named effect the others make redundant.
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
# under 2 ms is what an ordinary serial link's jitter (a few tenths of a ms) fits as.
# The setup's range is judged on the delays' scatter beyond the baseline link's, not on
# the hold-back parameter alone: a buffering link whose delays have a heavy tail (a
# reader that sometimes wakes late) is fitted by an exponential of ms-scale mean with
# no hold-back at all, and its delays scatter as much as a latency timer's. The
# ordinary link's bound on that scatter: a uniform hold-back of up to 2 ms, L/√12
ORDINARY_HOLD_BACK_S = 2e-3
ORDINARY_HOST_SCATTER_S = ORDINARY_HOLD_BACK_S / math.sqrt(12.0)

# the distance gain's interval: a bootstrap over the stops (each stop's error before and
# after resampled together), BOOTSTRAP_RESAMPLES draws from a fixed seed; a loss counts
# when the interval's upper end is below minus the estimator's own position standard
# deviation at the stops (one-sided 2.5 %), at any number of stops — with one stop (or the
# final position alone) the interval is that one value
DISTANCE_INTERVAL = 0.95
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20261127
# host timestamps matter when they misplace a sample by more than the board's own timing
# convention already allows (where in its period a sample reads: half a period)
HOST_SCATTER_PERIODS = 0.5

# physically possible values (data sheets of the ADXL202 family, mounts, boards)
MAX_SCALE_ERROR_FRAC = 0.20  # sensitivity 10–15 %/g around 12.5 %/g
MAX_QUADRATIC_PER_G = 0.03  # data sheet: ~0.2 % of full scale; 3 %/g is far beyond any part
MAX_DAMPING_RATIO = 0.5  # above, a "resonance" does not ring: it is a filter shape
MIN_BANDWIDTH_HZ = 2.0  # a mount or CX low-pass below 2 Hz would swallow the motion itself
MAX_DELAY_S = 0.25  # a reference logged more than ¼ s off is a clock problem, not a lag
MAX_TILT_RAD_PER_M = 0.5  # 29°/m: a rail or an arm turning the sensor that much
MAX_OFFSET_MG_PER_C = 10.0  # data sheet: order of mg/°C
# the die's thermal lag behind the board's thermometer (first order): the ADXL202E's
# ceramic LCC (5 × 5 × 2 mm, ≤ 0.2 g of alumina at 0.88 J/(g·K): ≤ 0.17 J/K) behind its
# pads' thermal resistance to the board (small packages' junction-to-board resistances
# in manufacturers' tables: 5–93 K/W; ≤ 100 K/W) gives τ ≤ 17 s, rounded up to 20 s; a
# small plastic package on a board is specified at about 2 s (TI TMP401/TMP464 data
# sheets: "thermal time constant approximately two seconds"); 0: no lag
MAX_DIE_LAG_S = 20.0
MAX_CROSS_GAIN = 0.15  # ±2 % cross-axis sensitivity + a few degrees of misalignment
MAX_TILT_IN_MOTION_DEG = 5.0  # a tool tilting more than 5° under its drive is a machine out of order
# host timing: a USB adapter's latency timer is at most 255 ms; a clock, even an RC
# oscillator (±2 %), is not tens of per cent off. Beyond: a logger's backlog or a host
# that fell behind — host times that are wrong, but not by a clock or a latency timer
MAX_HOLD_BACK_S = 0.255
MAX_CLOCK_RATE_ERROR = 0.02
# a host clock's step: ntpd steps an offset beyond 128 ms at once and below it slews
# (500 ppm at most), chrony's makestep and PTP step smaller ones; no synchronising daemon
# sets the clock by more than ntpd's panic threshold, 1000 s (beyond it ntpd refuses and
# exits): a larger jump is a clock set by hand or a logger's own time base, not a step
MAX_CLOCK_STEP_S = 1000.0


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
    # theta: (hold-back s, clock rate error, the delays' scatter beyond the baseline link's s)
    if name == "timing" and theta[0] < ORDINARY_HOLD_BACK_S and (len(theta) < 3 or theta[2] < ORDINARY_HOST_SCATTER_S):
        return (f"host arrival jitter fitted as a hold-back of {1e3 * theta[0]:.2f} ms: an ordinary link's "
                f"jitter (below {1e3 * ORDINARY_HOLD_BACK_S:g} ms, scatter below "
                f"{1e3 * ORDINARY_HOST_SCATTER_S:.2f} ms)")
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
        f, z, gain, quad = theta
        if math.hypot(gain, quad) > 1.0 / (2.0 * z):
            return (f"a ringing at {f:.0f} Hz of {math.hypot(gain, quad):.1f}× the mount's own response, beyond "
                    f"its resonance's amplification 1/(2ζ) = {1.0 / (2.0 * z):.1f}")
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
    if name == "motion_offset" and abs(theta[0]) > G * math.sin(math.radians(MAX_TILT_IN_MOTION_DEG)):
        return (f"an offset of {theta[0] / G * 1e3:.0f} mg in motion (a tool tilting more than "
                f"{MAX_TILT_IN_MOTION_DEG:g}° under its drive)")
    if name == "cross_talk" and abs(theta[0]) > MAX_CROSS_GAIN:
        return f"{100 * theta[0]:+.0f} % of the other axis's motion (beyond ±{100 * MAX_CROSS_GAIN:g} %)"
    if name == "temperature_offset" and abs(theta[0] / G * 1e3) > MAX_OFFSET_MG_PER_C:
        return f"{theta[0] / G * 1e3:.1f} mg/°C (data sheet: order of 1 mg/°C)"
    if name == "timing":  # theta: (hold-back s, clock rate error as a fraction, scatter s, clock step s)
        hold, rate = theta[:2]
        step = float(theta[3]) if len(theta) > 3 else 0.0
        if abs(step) > MAX_CLOCK_STEP_S:
            return (f"a host clock step of {step:+.0f} s (no synchronising daemon steps more than "
                    f"{MAX_CLOCK_STEP_S:g} s: a clock set by hand, or not a clock)")
        if hold > MAX_HOLD_BACK_S or abs(rate) > MAX_CLOCK_RATE_ERROR:
            return (f"host times held back up to {1e3 * hold:.0f} ms with a clock {1e6 * rate:+.0f} ppm off "
                    f"(a latency timer is at most {1e3 * MAX_HOLD_BACK_S:g} ms, a clock within "
                    f"±{100 * MAX_CLOCK_RATE_ERROR:g} %): a logger's backlog or a host that fell behind, "
                    "not a clock or a latency timer")
    return None


def residual_share(rms_before: float, rms_after: float) -> float:
    """The share of the residual variance an effect explains."""
    if not (rms_before > 0):
        return 0.0
    return 1.0 - (rms_after / rms_before) ** 2


def distance_interval(distance: dict) -> tuple[float, float] | None:
    """The DISTANCE_INTERVAL interval of the distance improvement (mm) from a bootstrap
    over the stops; None when no distance is available."""
    if not distance.get("available"):
        return None
    before, after = distance.get("before", {}), distance.get("after", {})
    if distance.get("metric") != "stop_rms_mm" or "stops_mm" not in before or "stops_mm" not in after:
        v = float(distance["improvement_mm"])
        return v, v
    b, a = np.asarray(before["stops_mm"], float), np.asarray(after["stops_mm"], float)
    if a.size != b.size or a.size < 2:
        v = float(distance["improvement_mm"])
        return v, v
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, a.size, size=(BOOTSTRAP_RESAMPLES, a.size))
    gain = np.sqrt(np.mean(b[idx] ** 2, axis=1)) - np.sqrt(np.mean(a[idx] ** 2, axis=1))
    tail = 100 * (1 - DISTANCE_INTERVAL) / 2
    lo, hi = np.percentile(gain, [tail, 100 - tail])
    return float(lo), float(hi)


def matters(distance: dict | None, host_scatter_periods: float | None = None,
            masked_by: str | None = None) -> tuple[bool, str]:
    """(named, why). A predictive, physical effect is named unless
    - its compensation makes the distance worse beyond its interval (harmful);
    - it is host timing whose delays scatter by less than HOST_SCATTER_PERIODS of a
      sample period (its residual share says nothing: side_effects.host_time_position_mm);
    - structure left in the residual explains more than it does (masked_by says what):
      a small effect is not named while a larger unexplained one stands."""
    interval = distance_interval(distance or {})
    # ...and beyond what the estimator itself says it knows the stops' positions to (its
    # own position standard deviation there, RMS over the stops, before the change): a
    # loss consistent over the stops but smaller than that is no harm anyone could see
    known = float((distance or {}).get("before", {}).get("stop_std_mm", 0.0) or 0.0)
    if interval is not None and interval[1] < -(known if math.isfinite(known) else 0.0):
        return False, (f"makes the distance error worse by {-float(distance['improvement_mm']):.2f} mm "
                       f"(interval {interval[0]:+.2f} … {interval[1]:+.2f} mm)")
    if host_scatter_periods is not None and host_scatter_periods < HOST_SCATTER_PERIODS:
        return False, (f"host delays scatter by {host_scatter_periods:.2f} of a sample period beyond the "
                       f"baseline's link: less than where in its period a sample reads ({HOST_SCATTER_PERIODS:g})")
    if masked_by:
        return False, f"smaller than what is left unexplained ({masked_by})"
    return True, ""
