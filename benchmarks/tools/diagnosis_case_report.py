"""What `adxlgw diagnose` said about one benchmark case, candidate by candidate.

    .venv/bin/python -m benchmarks.tools.diagnosis_case_report --effect temperature_offset --seeds 130008 130018
    .venv/bin/python -m benchmarks.tools.diagnosis_case_report --generator own --effect temperature_offset \
        --seeds 17 --parts tolerance --jerk-mps3 400 --dcm-reading edge

For each seed: the case as `diagnosis_benchmark.py` makes it (the independent generator,
testing/independent_generator, or the own simulator with the same options), the hidden truth, and the
diagnosis's verdict on every candidate (accepted / rejected and why, ΔBIC), its named
effects, setup properties, negligible and not-physical lists. With `--clean-twin` (own
simulator only): the smoothed estimate's error at each stop of the reference for the
recording as it is, for its clean twin (the same seed, part and noise without the hidden
effect) and, for temperature_offset, for the recording less the fitted k·(T_die − T̄_die) — whether
a compensation that "makes the distance worse" in fact makes it what it would be without
the effect (the effect had cancelled other errors there). A reading aid for a
benchmark row that is not met: it changes nothing, and what it shows about the
independent generator must not be tuned on (docs/diagnosis.md §7b, "How it was used").
"""
from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

import numpy as np

from benchmarks.harness import machine
from gateway.core.diagnosis import diagnose
from gateway.core.diagnosis.judgement import residual_share
from gateway.core.estimator import estimate_series
from gateway.core.evaluation import summarise_errors
from gateway.core.model_compensation import die_temperature_c
from gateway.core.sensor_model import DCM_READINGS
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.diagnosis_report import distance_text
from testing import diagnosis_cases as own
from testing.diagnosis_cases import estimator_settings
from testing.independent_generator import cases as independent

REPO = Path(__file__).resolve().parents[2]


def own_case(effect: str | None, seed: int, parts: str, jerk_mps3: float, dcm_reading: str,
             zero_g_offset_g: float | None = None):
    """The own simulator's case exactly as the benchmark builds it: (truth, data); with
    zero_g_offset_g, on the same part but for its zero-g offset."""
    terms, data, _ = own.build_case((effect,) if effect else (), seed, parts == "tolerance", jerk_mps3,
                                    dcm_reading, zero_g_offset_g)
    return terms, data


def report(effect: str | None, seed: int, args) -> list[str]:
    if args.generator == "own":
        truth, data = own_case(effect, seed, args.parts, args.jerk_mps3, args.dcm_reading, args.zero_g_offset_g)
    else:
        case = independent.make_case(effect, seed)
        truth, data = independent.truth_of(case), case.data
    result = diagnose(data, estimator_settings())
    out = [f"### {effect or 'clean'}, seed {seed}", "",
           f"truth: {truth}; named: {[e.name for e in result.effects] or 'nothing'}; "
           f"residual white: {result.residual_white}; noise model {result.noise_model}", ""]
    out.append("| candidate | status | ΔBIC | reason |")
    out.append("| --- | --- | --- | --- |")
    for c in result.candidates:
        out.append(f"| {c.name} | {c.status} | {c.delta_bic:.1f} | {c.reason} |")
    for e in result.effects:
        rms = e.gain.get("residual_rms_mps2")
        share = f"{100 * residual_share(*rms):.2f} %" if rms and rms[0] > 0 else "n/a"
        dist = e.gain.get("distance", {})
        out.append(f"- named: {e.name} {e.params}; residual share {share}; {distance_text(dist)}")
    for title, items in (("setup", result.setup), ("negligible", result.negligible),
                         ("not physical", result.not_physical)):
        for item in items:
            out.append(f"- {title}: {item}")
    if getattr(args, "clean_twin", False) and args.generator == "own":
        out += clean_twin_lines(effect, seed, args, data, result)
    return out + [""]


def track_stop_errors_mm(data, pos_m) -> np.ndarray:
    summary = summarise_errors(data.t_s, pos_m, data.ref_pos_m, data.ref_vel_mps)
    return np.array([s.error_m for s in summary.stops]) * 1e3


def stop_errors_mm(data, acc) -> np.ndarray:
    track = estimate_series(data.t_s, acc, data.valid, method="smoothed", settings=estimator_settings(),
                            lost_before=data.lost_before)
    return track_stop_errors_mm(data, track.pos_m)


def clean_twin_lines(effect, seed, args, data, result) -> list[str]:
    _, twin = own_case(None, seed, args.parts, args.jerk_mps3, args.dcm_reading, args.zero_g_offset_g)
    rows = [("as recorded", stop_errors_mm(data, data.acc_mps2)),
            ("clean twin (no hidden effect)", stop_errors_mm(twin, twin.acc_mps2))]
    corrected = result.distance.get("after")
    if corrected is not None:  # the diagnosis's own plan: every accepted effect (setup too) compensated
        rows.append(("as recorded, every accepted effect compensated", track_stop_errors_mm(data, corrected.pos_m)))
    fitted = {e["name"]: e["params"] for e in result.negligible}
    fitted.update({e.name: e.params for e in result.effects})
    if effect == "temperature_offset" and effect in fitted:
        k = fitted[effect]["offset_mg_per_c"][0] * 1e-3 * G
        lag_s = fitted[effect].get("die_lag_s", (0.0, 0.0))[0]
        temp = die_temperature_c(data.t_s, data.temperature_c, lag_s)  # the die's, as the candidate fits it
        rows.append((f"less the fitted {fitted[effect]['offset_mg_per_c'][0]:+.3f} mg/°C, die lag {lag_s:.2f} s",
                     stop_errors_mm(data, data.acc_mps2 - k * (temp - np.nanmean(temp)))))
    out = ["", "| smoothed estimate | error at each stop (mm) | RMS (mm) |", "| --- | --- | --- |"]
    for name, err in rows:
        out.append(f"| {name} | {', '.join(f'{x:+.2f}' for x in err)} | {np.sqrt(np.mean(err ** 2)):.2f} |")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--effect", default="temperature_offset", help="the hidden effect ('clean': none)")
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--generator", choices=("independent", "own"), default="independent")
    ap.add_argument("--parts", choices=("nominal", "tolerance"), default="nominal", help="own: the part")
    ap.add_argument("--jerk-mps3", type=float, default=0.0, help="own: strokes jerk-limited at this jerk")
    ap.add_argument("--dcm-reading", choices=DCM_READINGS, default="mean", help="own: where the modulator reads")
    ap.add_argument("--clean-twin", action="store_true",
                    help="own: the stop errors as recorded, of the clean twin, and less the fitted temperature term")
    ap.add_argument("--zero-g-offset-g", type=float, default=None,
                    help="own: the part's zero-g offset, g (default: the part's own)")
    args = ap.parse_args()
    effect = None if args.effect == "clean" else args.effect
    own_options = (f" --parts {args.parts} --jerk-mps3 {args.jerk_mps3:g} --dcm-reading {args.dcm_reading}"
                   + (" --clean-twin" if args.clean_twin else "")
                   + (f" --zero-g-offset-g {args.zero_g_offset_g:g}" if args.zero_g_offset_g is not None else "")
                   if args.generator == "own" else "")
    print(f"command: .venv/bin/python -m benchmarks.tools.diagnosis_case_report --generator {args.generator} "
          f"--effect {args.effect} --seeds {' '.join(map(str, args.seeds))}{own_options}")
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    print()
    for seed in args.seeds:
        print("\n".join(report(effect, seed, args)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
