"""What this record cannot tell apart: another cause that explains the same residual.

A named effect's shape may be matched, on one record, by another cause's: an offset
growing with travel (tilt) and an offset while moving (motion_offset) on a single move
at steady speed; a slow offset change (temperature) and the baseline's drift when the
temperature runs in line with time. The report then names them together and says what
would separate them.

Rule: for a named effect e, every other applicable candidate c is fitted in its place
(the other named effects kept). If the model with e does not predict the record's
blocks better than the model with c by more than chance — the out-of-block gain of e
over c at most the threshold one parameter reaches with probability α
(criterion.CvGain.threshold) — and c's fit is physically possible, c is not separable
from e here.

An effect the backward pass found redundant once the others were in is tried in a named
effect's place like any other candidate: what made it redundant may be a named effect
that explains the same residual.

A low-pass and the reference's own dynamics: linear filters commute, so a pole in the
sensor (or its mount) and the same pole between the reference and the axis (a servo
following its command, a filtered encoder) read the motion identically — no criterion
on the motion can place it. Where the reference is shown to have dynamics of its own (a
delay named: a late or leading reference), one cause — the reference reaching the
motion through a loop, which at the frequencies the motion holds is a lag and a
low-pass at once — explains what two (a sensor pole and a late reference) would: the
one cause is named, the low-pass listed as not separable from it
(`one_cause_for_the_reference_path`). The noise at rest separates them (a sensor's pole
shapes it, a reference's loop does not), or a reference measured at the axis.

Temperature against drift: the temperature's variance outside offset + drift, times the
largest coefficient a part has (judgement.MAX_OFFSET_MG_PER_C), whitened like the
residual, is what even the strongest temperature effect could show beyond the drift;
when that is below what the likelihood-ratio test detects at α (χ²₁), the two cannot
be told apart on this record.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from gateway.core.diagnosis.context import MIN_TEMPERATURE_STD_C, G, Prepared
from gateway.core.diagnosis.judgement import MAX_OFFSET_MG_PER_C, physical
from gateway.core.diagnosis.model_fit import ModelFit, current_signal, cv_gain_of, fit_model

# what separates each pair that one record may not: said beside the names
WHAT_SEPARATES = {
    frozenset({"tilt", "motion_offset"}): "a return stroke (it reverses the travel, not the motion)",
    frozenset({"tilt", "scale_factor"}): "moves of other lengths",
    frozenset({"temperature_offset", "drift"}): "a temperature swing (heat or cool the board and back)",
    frozenset({"reference_delay", "bandwidth"}): "the noise at rest (the sensor's own pole shapes it, a "
                                                 "reference's loop does not) or a reference measured at the axis",
}

# the reference path's own dynamics, and the filters that read the motion the same
# whether they sit in the sensor or in that path (module docstring)
REFERENCE_PATH_EFFECT = "reference_delay"
COMMUTING_FILTERS = ("bandwidth",)


def one_cause_for_the_reference_path(effects: list) -> list[str]:
    """Fold a named low-pass into a named reference delay (module docstring): the
    filter's result leaves `effects` and is listed in the delay's not_separable_from.
    Returns the names folded."""
    by_name = {e.name: e for e in effects}
    path = by_name.get(REFERENCE_PATH_EFFECT)
    if path is None:
        return []
    folded = [n for n in COMMUTING_FILTERS if n in by_name]
    for n in folded:
        effects.remove(by_name[n])
        if n not in path.not_separable_from:
            path.not_separable_from.append(n)
    return folded


def what_separates(a: str, b: str) -> str:
    return WHAT_SEPARATES.get(frozenset({a, b}), "a recording with other motions or conditions")


def alternatives(prep: Prepared, current: ModelFit, accepted: list, start: dict, others: list,
                 alpha: float) -> dict[str, list[str]]:
    """{named effect: the candidates that explain the same residual as well}."""
    out: dict[str, list[str]] = {}
    for e in accepted:
        if getattr(e, "setup_only", False):
            continue
        kept = [x for x in accepted if x is not e]
        twins = []
        base = fit_model(prep, tuple(kept), {x.name: start[x.name] for x in kept}, base_start=current.theta[:2])
        signal = current_signal(prep, base)  # the motion's reading as the others leave it
        for c in others:
            if getattr(c, "setup_only", False) or c is e:
                continue
            init = c.initial(prep, np.nan_to_num(base.residual), signal)
            alt = fit_model(prep, tuple(kept) + (c,), {**{x.name: start[x.name] for x in kept}, c.name: init},
                            base_start=current.theta[:2])
            theta = alt.effect_theta(c)[0]
            if physical(c.name, prep, theta) or getattr(c, "implausible", lambda p, t: None)(prep, theta):
                continue
            cv = cv_gain_of(prep, current, alt)
            if cv.total <= cv.threshold(alpha, 1):
                twins.append(c.name)
        out[e.name] = twins
    return out


def temperature_in_line_with_drift(prep: Prepared, alpha: float) -> str | None:
    """A sentence when even the largest temperature coefficient could not be told from
    the drift on this record; None when it could (or there is no usable temperature)."""
    d = prep.data
    if not d.column_ok("temp_c", min_std=MIN_TEMPERATURE_STD_C):
        return None
    temp = d.temperature_c
    fill = float(np.nanmean(temp))
    x = np.nan_to_num(temp, nan=fill) - fill
    m = prep.fit_mask
    cols = np.column_stack([np.ones(x.size), prep.drift_shape])
    coef = np.linalg.lstsq(cols[m], x[m], rcond=None)[0]
    perp = x - cols @ coef
    share_in_line = 1.0 - float(np.var(perp[m])) / max(float(np.var(x[m])), 1e-300)
    largest = MAX_OFFSET_MG_PER_C * 1e-3 * G  # m/s² per °C
    w = prep.whiten_masked(largest * perp, m)
    noise = prep.whiten_masked(np.nan_to_num(d.acc_mps2 - prep.reading_mps2), m)
    var = float(np.var(noise))
    reach = float(np.dot(w, w)) / max(var, 1e-300)
    if reach >= float(chi2.isf(alpha, 1)):
        return None
    return (f"temperature and drift cannot be told apart here: {100 * share_in_line:.2f} % of the temperature's "
            f"variance lies in offset + drift, and even {MAX_OFFSET_MG_PER_C:g} mg/°C would leave less than the "
            f"test can see; {what_separates('temperature_offset', 'drift')} would separate them")
