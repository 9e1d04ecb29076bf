"""The standstill detector — and why a cruise is not a standstill.

During the constant-velocity part of a stroke the acceleration is zero, exactly as at
rest: a detector that looks only at a window of acceleration calls the cruise a
standstill and resets a real 1 m/s to zero. So a sample is a standstill only when all
three tests pass on the window of the last W samples (standstill_window_s):

1. variance: the window's sample variance is what the sensor noise alone gives —
   s² ≤ σ²·χ²_ν(1 − p)/ν, with σ the per-sample noise, ν the window's effective
   degrees of freedom for correlated noise, p the false-"motion" probability — or, if
   not, the window is a vibration: its acceleration, the bias removed, swings the
   velocity by no more than standstill_vibration_mps (a robot arm settling after a stop; the
   noise level is measured at the quiet initial rest). Any change of acceleration that
   moves the axis fails it.
2. mean: the window's mean equals the current bias estimate, |m − b| ≤ n·√(R/W + P_bb)
   (R/W: the mean's variance for white-equivalent noise of density N). A slow, steady
   acceleration that passes the variance test fails this one.
3. velocity: the filter's own velocity is below the floor, |v| ≤ v_floor, and the
   filter knows it well enough to tell: n·σ_v ≤ v_floor. This is what tells a cruise
   from a standstill: after a 10 m/s² ramp to 1 m/s, v ≈ 1 m/s with σ_v of mm/s.
   v_floor (an application choice, settings) is the slowest cruise that must never be
   called a standstill; it also covers errors the model lacks (tilt, scale). When
   n·σ_v > v_floor the test is undecidable (a cruise at the floor speed and a stop look
   the same to the filter) and fails: the estimator says so (F_UNTRUSTED) instead.

Before the filter is initialised there is no velocity or bias yet: the first window
that passes the variance test is the reference point (the filter starts there, at rest,
at position 0). Test 3 is trivially true while at standstill (v ≡ 0), so leaving a
standstill is decided by tests 1–2 alone — a 10 m/s² start fails both on its first
sample. A window with fewer than 80 % valid samples decides nothing: the previous
regime is held and the health flags say so.

A machine's "at rest" hint is a gate (hint_gate_open): a whole window inside the hinted
rest whose mean sits at the bias within its own spread is a standstill, whatever the
filter's velocity; velocity_consistent_with_rest then says whether the stop's velocity is
chance (χ²₁ at the detector's false-alarm rate) or a disagreement the kernel flags.

A machine's "at rest" hint over a rest shorter than the window, or while the mount rings
after the stop (the variance test failing on a swing above standstill_vibration_mps), is
no standstill these tests can accept — yet it still says the axis stands: its velocity
swings about zero, its mean over the hinted samples is zero. hinted_rest_fits says
whether the hinted samples contradict the hint; mean_velocity_offset gives the velocity
now against their mean and its range; the kernel then applies a soft velocity update
(kernel_update.soft_hinted_update), not a standstill.
"""
from __future__ import annotations

import math

from gateway.core.jit import jit

# The fewest samples any spread is judged on: the detector's window (the floor of
# EstimatorSettings.window_samples) and the hinted samples of a soft hinted velocity update
# (hinted_rest_fits). A mean judged against the spread of n samples has n − 1 degrees of
# freedom: at 3 a Student t beyond 5 comes by chance 1.5 % of the time, at 1 (two
# samples) 13 % — fewer samples would call noise a deceleration.
MIN_WINDOW_SAMPLES = 4


@jit
def window_statistics(ring_z, ring_ok, oldest, count):
    """(number of valid samples, their mean, their variance) over `count` slots of the ring
    from slot `oldest` on (wrapping around the ring; two passes)."""
    size = ring_z.size
    n = 0
    total = 0.0
    for i in range(count):
        j = (oldest + i) % size
        if ring_ok[j] > 0.0:
            n += 1
            total += ring_z[j]
    if n < 2:
        return n, 0.0, 0.0
    mean = total / n
    ss = 0.0
    for i in range(count):
        j = (oldest + i) % size
        if ring_ok[j] > 0.0:
            d = ring_z[j] - mean
            ss += d * d
    return n, mean, ss / (n - 1)


@jit
def velocity_swing(ring_z, ring_ok, oldest, count, bias, period_s):
    """Largest |Σ (z − bias)·Ts| along `count` slots of the ring in time order (from slot
    `oldest` on, wrapping around): how far their acceleration moves the velocity. Vibration
    of a mount at rest swings it by mm/s; the start of a motion by far more."""
    size = ring_z.size
    c = 0.0
    peak = 0.0
    for i in range(count):
        j = (oldest + i) % size
        if ring_ok[j] > 0.0:
            c += (ring_z[j] - bias) * period_s
            if abs(c) > peak:
                peak = abs(c)
    return peak


@jit
def true_velocity_swing(ring_z, ring_ok, oldest, count, bias, period_s, lag_s):
    """Largest |change of the true velocity| along `count` slots of the ring in time order
    (from slot `oldest` on), the sensor's lag undone. The true acceleration is u = y + τẏ
    (y = z − bias), so between two instants the true velocity changes by ∫y dt + τ·Δy. A
    sample is its period's mean, so the instants taken are the boundaries between valid
    slots, y there the mean of the two slots around it (a slot's own mean stands for its
    middle, not its start: with τ about one period, as the board's 3.2 ms at 2 ms, the
    decay inside the first slot would otherwise read as a swing of τ·(y(start) − ȳ)).
    A sensor's filter settling after a stop (y decaying with τ) then changes the true
    velocity by nothing, to second order; velocity_swing would count τ·y_0 of it."""
    size = ring_z.size
    c = 0.0
    peak = 0.0
    first = math.nan
    prev = math.nan
    for i in range(count):
        j = (oldest + i) % size
        if ring_ok[j] > 0.0:
            y = ring_z[j] - bias
            if not math.isnan(prev):
                at_boundary = 0.5 * (prev + y)
                if math.isnan(first):
                    first = at_boundary
                else:
                    c += prev * period_s  # the slot between the previous boundary and this one
                v = c + lag_s * (at_boundary - first)
                if abs(v) > peak:
                    peak = abs(v)
            prev = y
    return peak


@jit
def velocity_changes_beyond_noise(swing, n, sample_var_white, period_s, sigmas):
    """The velocity swing of n samples' acceleration (true_velocity_swing) is beyond what
    their white noise integrates to: more than sigmas standard deviations of the sum of n
    samples' noise, √(n·σ²)·Ts (σ²: one sample's white-equivalent variance, the ZARU's R;
    the largest partial sum of a white walk passes sigmas·σ_n with at most 4·P(Z > sigmas),
    the reflection principle). Then the samples hold part of a motion —
    the end of a deceleration, a start —, not the rest alone: a stop the machine's word
    puts among them may lie anywhere in them, or after them."""
    return swing > sigmas * math.sqrt(max(sample_var_white * n, 0.0)) * period_s


@jit
def velocity_decidable(vel_var, vel_sigmas, speed_floor):
    """The filter knows its velocity well enough to tell a stop from a cruise at the floor
    speed: vel_sigmas·σ_v ≤ v_floor (test 3)."""
    return vel_sigmas * math.sqrt(max(vel_var, 0.0)) <= speed_floor


@jit
def standstill_tests(initialised, n_valid, mean, var, vel, vel_var, bias, bias_var,
                     var_max, sample_var_white, mean_sigmas, vel_sigmas, speed_floor):
    """(variance ok, mean ok, velocity ok, velocity decidable) for one window; see the module docstring.

    The velocity test can only tell a stop from a cruise at the floor speed while the
    filter knows its velocity well enough: vel_sigmas·σ_v ≤ v_floor. Past that (after a
    gap, an outage, a long time without a stop) it is undecidable and never passes — a
    quiet stretch is then not accepted as a stop on the strength of a velocity the filter
    no longer has."""
    var_ok = var <= var_max
    if not initialised:
        return var_ok, True, True, True
    mean_ok = abs(mean - bias) <= mean_sigmas * math.sqrt(sample_var_white / n_valid + bias_var)
    decidable = velocity_decidable(vel_var, vel_sigmas, speed_floor)
    vel_ok = decidable and abs(vel) <= speed_floor
    return var_ok, mean_ok, vel_ok, decidable


@jit
def stopping_within_a_window(mean_off_bias, vel, window_s):
    """The window's acceleration (its mean less the bias) opposes the filter's velocity
    and, held, brings the axis to rest within about a window (|v| ≤ 2·|a|·window): the
    last part of a deceleration into a stop. A steady deceleration is as quiet in
    variance as a stretch whose offset stepped, and off the bias alike; told apart by
    where the velocity goes. An offset step in motion leaves a velocity error that grows
    with the time since it (seconds: far more than a window's worth of the step) and has
    no reason to oppose it; an offset step at rest makes the velocity follow it."""
    return mean_off_bias * vel < 0.0 and abs(vel) <= 2.0 * abs(mean_off_bias) * window_s


@jit
def hinted_rest_fits(ring_z, ring_ok, oldest, count, bias, bias_var, sample_var_white, step_max,
                     mean_sigmas, speed_floor, period_s):
    """The `count` hinted samples of the ring from slot `oldest` on do not contradict the
    machine's "at rest":
    - at least MIN_WINDOW_SAMPLES valid ones;
    - no acceleration or deceleration of the machine: their mean is off the bias by no more
      than an offset step (step_max) plus mean_sigmas of its own uncertainty, taken from
      their own spread (at least the noise's). A steady deceleration sits off the bias by
      more than its spread; a ringing mount swings about the bias, its spread covering how
      far a partial period's mean strays;
    - a velocity swing of their acceleration (bias removed) no larger than the speed floor:
      a velocity change beyond the slowest cruise the application must tell from a stop is
      a move, not a ringing mount."""
    n, mean, var = window_statistics(ring_z, ring_ok, oldest, count)
    if n < MIN_WINDOW_SAMPLES:
        return False
    spread = max(var, sample_var_white)
    if abs(mean - bias) > step_max + mean_sigmas * math.sqrt(spread / n + bias_var):
        return False
    return velocity_swing(ring_z, ring_ok, oldest, count, bias, period_s) <= speed_floor


@jit
def mean_velocity_offset(ring_z, ring_ok, oldest, count, bias, period_s):
    """(v_now − mean v, half the range of v) over the `count` ring slots from `oldest` on,
    the velocity at each sample's start known up to one constant from the acceleration
    before it (the bias removed); the last slot is the current sample, whose own
    acceleration acts after now."""
    size = ring_z.size
    c = 0.0
    total = 0.0
    lo = 0.0
    hi = 0.0
    for i in range(count):
        # velocity at the start of slot i, relative to the first's
        total += c
        if c < lo:
            lo = c
        if c > hi:
            hi = c
        j = (oldest + i) % size
        if ring_ok[j] > 0.0:
            c += (ring_z[j] - bias) * period_s
    # c now includes the current sample; the velocity now is the one before it
    j = (oldest + count - 1) % size
    now = c - ((ring_z[j] - bias) * period_s if ring_ok[j] > 0.0 else 0.0)
    return now - total / count, 0.5 * (hi - lo)


@jit
def hint_gate_open(hint_run, window, n_valid, mean, var, bias, bias_var, sample_var_white, mean_sigmas):
    """The machine's "at rest" and the accelerometer agree: a whole window lies inside the
    hinted rest (the word may lead the sensor's stop by a PLC cycle and a servo's settling:
    the samples before it are not judged) and the window's mean sits at the bias within
    mean_sigmas of the mean's own uncertainty — its spread (at least the noise's) over the
    samples, and the bias's. A ringing mount swings about the bias (a wide spread, a mean at
    the bias); a deceleration sits off it by more than its spread allows. The filter's own
    velocity is not asked: it is what the stop corrects (velocity_consistent_with_rest says
    whether the two agree)."""
    if hint_run < window or n_valid < 2:
        return False
    spread = max(var, sample_var_white)
    return abs(mean - bias) <= mean_sigmas * math.sqrt(spread / n_valid + bias_var)


@jit
def velocity_consistent_with_rest(vel, vel_var, scale_var, zupt_var, chi2_max):
    """A stop's velocity innovation is chance: v²/(σ_v² + s²·v² + R) ≤ χ²₁(1 − p) — the
    filter's velocity variance, the sensitivity's share of the velocity (a reading (1 + s)·a
    is off by s·v), the update's own noise."""
    return vel * vel <= chi2_max * (vel_var + scale_var * vel * vel + zupt_var)
