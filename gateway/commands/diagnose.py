"""adxlgw diagnose: what the simulation gets wrong about a recording, the cause, the gain."""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass

import numpy as np

from gateway.commands.estimate import settings_for
from gateway.core.diagnosis import DiagnosisInput, diagnose, list_effects
from gateway.core.diagnosis.context import reference_resolution_block
from gateway.core.diagnosis.judgement import REFERENCE_INTERVALS_PER_BLOCK
from gateway.core.diagnosis.timestamps import TimestampError, check_sample_clock
from gateway.core.estimator_settings import EstimatorSettings, from_sensor_model
from gateway.core.model_compensation import ModelTerm, SensorModel
from gateway.core.reference_point import NoRestError
from gateway.core.sensor_model import SensorParams
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.errors import InputError
from gateway.offline.diagnosis_report import jsonable, text_summary, write_report
from gateway.offline.progress import reading_bar
from gateway.offline.recording import REFERENCE_COLUMNS, open_recording, read_all, to_acceleration
from gateway.sensor_model_file import write_sensor_model

# below this the noise model, the whiteness test and the block means have too little to go on
MIN_VALID_SAMPLES = 200


def add_parser(sub) -> None:
    p = sub.add_parser(
        "diagnose",
        help="what the simulation gets wrong about a recording, the cause, the gain",
        description="Compare a recording with the baseline sensor model (offset, drift, noise), look for "
                    "each known effect the model lacks (--list-effects), accept one only on strong evidence "
                    "(BIC and a likelihood-ratio test), and measure what it gains: residual, likelihood, "
                    "distance error. With the reference motion in the file (ref_pos_m, ref_vel_mps, "
                    "ref_acc_mps2) every effect can be looked for; without it the smoothed estimate stands in "
                    "and only some can. Says what cannot be analysed and why.",
    )
    p.add_argument("recording", metavar="FILE.csv", nargs="?",
                   help="the recording (either form; CSV, or Parquet: .parquet)")
    p.add_argument("--json", metavar="OUT.json", help="write the full result as JSON")
    p.add_argument("--report", metavar="DIR", help="write DIR/report.md with plots (residual, spectrum, Allan "
                                                   "deviation, position error; before and after)")
    p.add_argument("--returns-to-start", action="store_true",
                   help="the motion ends where it began: without a reference, the final position is the "
                        "distance error the gain is measured by")
    p.add_argument("--other-axis-still", action="store_true",
                   help="the other axis does not move in this recording: only then is cross_axis looked for "
                        "(without a reference for it, its own motion would read as cross-talk)")
    p.add_argument("--reference-block", type=int, metavar="N",
                   help="compare model and measurement as means over N samples (default: 1 for a reference that "
                        "resolves every sample, 4 of its own intervals for a coarse one, e.g. a robot position "
                        "at a few Hz)")
    p.add_argument("--model-out", metavar="M.json",
                   help="write the extended model (the effects named or kept as the setup's, with their parameters) "
                        "for adxlgw estimate --model and the daemon's [model] file")
    p.add_argument("--model-with", metavar="NAME[,NAME]", default="",
                   help="also write these candidates' fitted terms into --model-out, named or not (a cause the "
                        "user knows of, to be tried on other recordings; the model file notes that the diagnosis "
                        "did not name it, and why)")
    p.add_argument("--list-effects", action="store_true", help="list the effects looked for and exit")
    p.set_defaults(run=run, _parser=p)


def _warn(msg: str) -> None:
    print(f"adxlgw diagnose: warning: {msg}", file=sys.stderr)


def _progress(msg: str) -> None:
    print(f"diagnose: {msg}", file=sys.stderr)


def build_input(path: str, rec, series, notes: list[str], other_axis_still: bool = False,
                reference_block: int | None = None) -> DiagnosisInput:
    ref = series.reference
    present = [k for k in REFERENCE_COLUMNS if k in ref]
    complete = len(present) == len(REFERENCE_COLUMNS)
    usable = "ref_pos_m" in ref
    pos = vel = acc = None
    if usable:
        # a position reference as users have it (robot, encoder, laser): what it lacks is
        # derived from it, and the comparison is made at its own resolution
        pos = ref["ref_pos_m"]
        vel = ref["ref_vel_mps"] if "ref_vel_mps" in ref else np.gradient(pos, series.t_s)
        acc = ref["ref_acc_mps2"] if complete else np.gradient(vel, series.t_s)
        if not complete:
            missing = [k for k in REFERENCE_COLUMNS if k not in ref]
            notes.append(f"reference without {', '.join(missing)}: derived from the position, and model and "
                         "measurement compared at the reference's own resolution")
    elif present:
        notes.append(f"reference incomplete (has {', '.join(present)}, lacks ref_pos_m): it is not used")
    block = 1
    if usable and reference_block is not None:
        block = reference_block
    elif usable:
        moving = np.abs(vel) > 1e-6
        step = reference_resolution_block(series.t_s, pos, moving)
        if step > 1:
            # velocity from one interval of a logged position carries its timestamps' jitter
            # (v·δt / interval): several intervals per block average it down
            block = REFERENCE_INTERVALS_PER_BLOCK * step
            period_ms = float(np.median(np.diff(series.t_s))) * 1e3
            notes.append(f"the reference bends every {step} samples ({step * period_ms:.0f} ms): it resolves no "
                         "acceleration within that; model and measurement are compared as means over "
                         f"{block} samples ({block * period_ms:.0f} ms, {REFERENCE_INTERVALS_PER_BLOCK} of its "
                         "intervals: velocity changes)")
    sensor = SensorParams()
    raw = rec.form == "raw"
    return DiagnosisInput(
        t_s=series.t_s,
        acc_mps2=series.acc_mps2,
        valid=series.valid,
        lost_before=series.lost_before,
        reference="recorded" if usable else None,
        ref_pos_m=pos,
        ref_vel_mps=vel,
        ref_acc_mps2=acc,
        other_mps2=series.other_axis_mps2,
        temp_c=series.temp_c,
        t_host_s=series.t_host_s,
        # the ADXL202's CX filter for the board's own counts; a foreign sensor's filter is unknown
        sensor_bandwidth_hz=sensor.bandwidth_hz if raw else None,
        # the ADXL202 saturates at ±2 g; a foreign sensor's range is not known
        range_mps2=sensor.range_g * STANDARD_GRAVITY_MPS2 if raw else math.inf,
        raw_form=raw,
        other_axis_still=other_axis_still,
        reference_block=block,
        standstill_hint=series.standstill_hint,
    )


def _nothing(path: str, why: str) -> InputError:
    return InputError(f"{path}: nothing to analyse: {why}")


def run(args: argparse.Namespace) -> int:
    """The diagnosis; with --json the file is written whatever happens: the result, or
    {"error": …, "exit_code": …} when the recording cannot be analysed (2) or the
    diagnosis itself failed (1, a bug: the traceback is printed too)."""
    try:
        return _run(args)
    except InputError as err:
        _write_error_json(args, err, err.exit_code)
        raise
    except Exception as err:
        _write_error_json(args, err, 1)
        raise


def model_of(result, path: str, also: list[str]) -> SensorModel:
    """The extended model: the terms the diagnosis named or kept as the setup's, then any
    candidate asked for (--model-with) with its fitted parameters and a note saying why it
    was not named."""
    terms = [ModelTerm(t["name"], t["params"]) for t in result.model_terms]
    notes = []
    have = {t.name for t in terms}
    by_name = {c.name: c for c in result.candidates}
    for name in also:
        c = by_name.get(name)
        if c is None:
            raise InputError(f"--model-with {name}: not a candidate (adxlgw diagnose --list-effects)")
        if name in have:
            continue
        if not c.model_params:
            raise InputError(f"--model-with {name}: not fitted on this recording ({c.status}: {c.reason})")
        terms.append(ModelTerm(name, c.model_params))
        notes.append(f"{name}: added by --model-with; the diagnosis did not name it ({c.status}: {c.reason})")
    return SensorModel(tuple(terms), source=path, notes=tuple(notes))


def _write_error_json(args: argparse.Namespace, err: Exception, code: int) -> None:
    if not getattr(args, "json", None) or args.list_effects:
        return
    try:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"error": str(err), "exit_code": code}, fh, indent=2, ensure_ascii=False)
            fh.write("\n")
    except OSError:
        pass  # the error that brought us here is the one reported


def _write_json(path: str, doc: dict) -> None:
    try:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=2, allow_nan=False, ensure_ascii=False)
            fh.write("\n")
    except OSError as err:
        raise InputError(f"{path}: cannot write: {err.strerror or err}") from err


@dataclass
class _Prepared:
    """A recording read, checked and made ready for the diagnosis."""

    path: str
    series: object  # AccelerationSeries
    data: DiagnosisInput
    settings: EstimatorSettings
    #: what the preparation could not do as asked, said before the result
    notes: list[str]


_NO_REST = ("no reference motion and no standstill to start the smoothed estimate from "
            "(record a rest at the start, or add ref_pos_m, ref_vel_mps, ref_acc_mps2)")


def _print_effects() -> None:
    effects = list_effects()
    width = max(len(name) for name, _ in effects)
    for name, summary in effects:
        print(f"{name.ljust(width)}  {summary}")


def _prepare(args: argparse.Namespace) -> _Prepared:
    """Reads the recording and checks it is one the diagnosis can work on (InputError
    naming what is wrong otherwise)."""
    path = args.recording
    source = open_recording(path)
    with reading_bar(source) as bar:
        rec = read_all(source, progress=bar)
    series = to_acceleration(rec)
    for w in series.report.warnings():
        _warn(w)
    n_valid = int(np.count_nonzero(series.valid))
    if n_valid < MIN_VALID_SAMPLES:
        raise _nothing(path, f"{n_valid} valid samples, the diagnosis needs at least {MIN_VALID_SAMPLES}")
    notes: list[str] = []
    if args.reference_block is not None and args.reference_block < 1:
        raise InputError(f"--reference-block {args.reference_block}: must be a whole number of samples ≥ 1")
    data = build_input(path, rec, series, notes, other_axis_still=args.other_axis_still,
                       reference_block=args.reference_block)
    try:  # before any analysis: an estimate on arrival stamps would be nonsense (timestamps.py)
        check_sample_clock(data.t_s, data.lost_before)
    except TimestampError as err:
        raise InputError(f"{path}: {err}") from err
    try:
        settings = settings_for(series, rec.form, "auto", None)
    except NoRestError as err:
        if data.reference is None:
            raise _nothing(path, f"{_NO_REST}: {err}") from err
        # a reference is there: the fit needs no rest; the filter takes the data-sheet noise
        notes.append(f"no initial rest for the filter's noise settings ({err}): the ADXL202 data-sheet "
                     "values are used, so the distance gains are indicative only")
        settings = from_sensor_model(SensorParams(), axis=series.axis)
    return _Prepared(path, series, data, settings, notes)


def _diagnosed(prepared: _Prepared, returns_to_start: bool):
    """The diagnosis of a prepared recording (InputError when it cannot be analysed)."""
    path, data = prepared.path, prepared.data
    try:
        result = diagnose(data, prepared.settings, returns_to_start=returns_to_start, progress=_progress)
    except NoRestError as err:
        if data.reference is None or data.reference == "estimated":
            raise _nothing(path, f"{_NO_REST}: {err}") from err
        raise InputError(f"{path}: cannot analyse: {err}") from err
    except ValueError as err:
        raise InputError(f"{path}: cannot analyse: {err}") from err
    result.cannot[:0] = prepared.notes
    return result


def _report(args: argparse.Namespace, prepared: _Prepared, result) -> None:
    """The summary on stdout and the files asked for (--json, --model-out, --report)."""
    path = prepared.path
    for c in result.cannot[len(prepared.notes):]:
        _warn(c)
    print(text_summary(result, path))
    if args.json:
        _write_json(args.json, jsonable(result.to_dict()))
        print(f"wrote {args.json}")
    if args.model_out:
        model = model_of(result, path, [n.strip() for n in args.model_with.split(",") if n.strip()])
        write_sensor_model(args.model_out, model)
        print(f"wrote {args.model_out}: {len(model.terms)} term(s)"
              + (f"; not compensated: {', '.join(model.not_compensated)}" if model.not_compensated else ""))
    if args.report:
        ref_pos = prepared.series.reference.get("ref_pos_m") if prepared.data.reference == "recorded" else None
        files = write_report(args.report, result, path, ref_pos)
        print(f"wrote {files[0]} and {len(files) - 1} plots")


def _run(args: argparse.Namespace) -> int:
    if args.list_effects:
        _print_effects()
        return 0
    if not args.recording:
        args._parser.error("the following arguments are required: FILE.csv (or --list-effects)")
    prepared = _prepare(args)
    for note in prepared.notes:
        _warn(note)
    result = _diagnosed(prepared, args.returns_to_start)
    _report(args, prepared, result)
    return 0
