"""The horizontal robot moves (datasets/leiria-robot/*_y605.csv): what the diagnosis finds,
and the extended model's gain measured predictively — fitted on one sensor's recording,
applied to the other sensors' recordings of the same move.

    .venv/bin/python -m benchmarks.accuracy.diagnosis_horizontal [--out DIR] [--model-with tilt]

Each file becomes an acceleration-form recording: t_s = sensor_time_s (the sensor's own
clock), the measured axis = acc_along_g (parallel to the robot's y; ≈ 0 g at rest), the
other axis = acc_cross_g, t_host_s = arrival_time_s, ref_pos_m = ref_m (the robot's
~14 Hz position as a user has it), standstill_hint = robot_at_rest. Then, per file:

1. `adxlgw diagnose REC --json D.json --model-out M.json --model-with NAMES`: the
   verdict, and the model (named terms, and the candidates asked for with their fitted
   parameters even where the diagnosis did not name them — the file says why);
2. `adxlgw estimate REC --method smoothed [--model M_k.json]` for every model k: the final
   position error after the move (the robot stands at 605 mm) without and with each
   sensor's model. Off the diagonal the gain is predictive: the model never saw that
   recording. Twice: with the recording's standstill hint (what `adxlgw estimate` does by
   default, and what the diagnosis's own gains are of) and with `--ignore-hint` (where the
   model is the only information on the move: the hinted end rest already measures the
   velocity error). Both tables are printed; neither is picked. A cell whose correction did
   not settle (`estimate --model`'s passes alternate) is one of several answers: marked
   "not determined", its gain counted neither for nor against (`predictive_gain_mm`).
3. Why the fitted tilt does not carry (docs/diagnosis.md §8), per file: κ as the
   diagnosis fits it (the baseline + tilt, the noise model from the rests) with its own σ;
   κ refitted with each of the criterion's blocks left out in turn (its range, and the
   block that moves it most); the baseline residual's spread over the blocks in motion
   against the rests' (the noise model knows only the rests); and how far the hinted and
   the unhinted final error move for a tilt of 0.01 rad/m (`estimate --model`, the
   estimate's own position).
4. One tilt for the whole run (what a joint fit of the four sensors would give, at
   best): the hinted final error of every file for each of a few κ, and on how many
   files it improves.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import json
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.harness import machine
from gateway.cli import main as adxlgw
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import read_recording, to_acceleration, write_recording

REPO = Path(__file__).resolve().parents[2]

FILES = ("eV50p_MPU6050RM3100_y605", "eV50p_LSM9DS0_y605", "eV50p_SENTRAL_y605", "V1000_LSM9DS0_y605")


def convert(src: Path, dst: Path) -> None:
    d = np.genfromtxt(src, delimiter=",", names=True)
    write_recording(dst, {"source": "import", "origin": src.name, "axis": "x"}, {
        "t_s": d["sensor_time_s"], "acc_x_mps2": d["acc_along_g"] * G, "acc_y_mps2": d["acc_cross_g"] * G,
        "t_host_s": d["arrival_time_s"], "ref_pos_m": d["ref_m"], "standstill_hint": d["robot_at_rest"],
    })


def quiet(argv: list[str]) -> int:
    return quiet_with_notes(argv)[0]


def quiet_with_notes(argv: list[str]) -> tuple[int, str]:
    """The command's exit code and what it wrote to stderr (its notes)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = adxlgw(argv)
    return code, err.getvalue()


def unsettled_mm(notes: str) -> float | None:
    """How far `estimate --model`'s last pass still moved the position, when its passes
    did not settle (model_compensation.CompensatedEstimate.describe); None when they did."""
    m = re.search(r"did not settle .*? by up to ([\d.]+) mm", notes)
    return float(m.group(1)) if m else None


def predictive_gain_mm(without_mm: float, with_mm: float, moved_mm: float | None) -> float | None:
    """|error| without − with the model, where the model gives one answer; None (not
    determined: counted neither for nor against) where its passes did not settle — the
    rule of gain.distance_gain for the diagnosis's own gains."""
    return None if moved_mm is not None else abs(without_mm) - abs(with_mm)


def with_model_cell(err_mm: float, moved_mm: float | None, own: bool = False) -> str:
    """A table cell: the error with the model, and whether it is one answer."""
    return (f"{err_mm:+.1f}" + (" (own)" if own else "")
            + (f" (not determined: passes differ by {moved_mm:.1f} mm)" if moved_mm is not None else ""))


def final_error_mm(rec: Path, track_csv: Path) -> float:
    """The estimate's position at the end against the reference's (the final rest)."""
    ref = to_acceleration(read_recording(rec)).reference["ref_pos_m"]
    est = np.genfromtxt(track_csv, delimiter=",", names=True, comments="#")
    return float(est["pos_m"][-1] - (ref[-1] - ref[0])) * 1e3


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=None,
                   help="working directory, kept (default: a private temporary one, removed at the end)")
    p.add_argument("--model-with", default="tilt", help="passed to diagnose --model-with (default: tilt)")
    args = p.parse_args()
    if args.out is None:
        with tempfile.TemporaryDirectory(prefix="adxlgw-diagnosis-horizontal-") as tmp:
            return run(args, Path(tmp))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return run(args, out)


def run(args, out: Path) -> int:
    """Diagnose each file in `out`, then carry each model to the others (the tables)."""
    print(f"command: .venv/bin/python -m benchmarks.accuracy.diagnosis_horizontal --model-with {args.model_with}")
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    recs, models = {}, {}
    for name in FILES:
        rec = out / f"{name}.recording.csv"
        convert(REPO / "datasets" / "leiria-robot" / f"{name}.csv", rec)
        recs[name] = rec
        d_json, m_json = out / f"{name}.diagnosis.json", out / f"{name}.model.json"
        code = quiet(["diagnose", str(rec), "--json", str(d_json), "--model-out", str(m_json),
                      "--model-with", args.model_with])
        doc = json.loads(d_json.read_text())
        if code != 0:
            print(f"{name}: diagnose exit {code}: {doc.get('error')}")
            continue
        models[name] = m_json
        named = [e["name"] + (f" (not separable from {', '.join(e['not_separable_from'])})"
                              if e.get("not_separable_from") else "") for e in doc["effects"]]
        model = json.loads(m_json.read_text())
        terms = ", ".join(f"{t['name']} " + " ".join(f"{k}={v:.4g}" for k, v in t["params"].items())
                          for t in model["effects"])
        print(f"{name}: named {', '.join(named) or 'nothing'}; model: {terms or 'no terms'}")
        for c in doc["candidates"]:
            if c["name"] in args.model_with.split(","):
                print(f"    {c['name']}: {c['status']} — {c['reason']}")
    for hinted in (True, False):
        _error_table(recs, models, out, hinted)
    print()
    print("why the fitted tilt does not carry: κ per file, its spread, the hinted estimate's response")
    for rec in recs.values():
        print(tilt_evidence(rec, out))
    common_tilt_table(recs, out)
    return 0


PROBE_TILT_RAD_PER_M = 0.01  # the tilt whose effect on the final error is measured (≈ the σ of κ fitted here)


def tilt_evidence(rec: Path, out: Path) -> str:
    """One file's evidence on the tilt (module docstring, step 3)."""
    from gateway.commands.diagnose import build_input
    from gateway.core.diagnosis.context import prepare
    from gateway.core.diagnosis.criterion import block_ids
    from gateway.core.diagnosis.model_fit import fit_model
    from gateway.core.diagnosis.reading import fit_noise_model
    from gateway.core.diagnosis.signal_effects import Tilt
    from gateway.offline.recording import read_recording as read

    raw = read(rec)
    full = build_input(str(rec), raw, to_acceleration(raw), [])
    tilt = Tilt()

    def prepared(data):
        prep = prepare(data)
        base = fit_model(prep, ())
        prep.noise = fit_noise_model(prep.noise_series(base.residual))
        return prep, fit_model(prep, ())

    def kappa(prep, mask) -> tuple[float, float]:
        prep.fit_mask = mask
        fit = fit_model(prep, (tilt,), start={"tilt": np.array([0.0])})
        value, std = fit.effect_theta(tilt)
        return float(value[0]), float(std[0])

    # the comparison's blocks are laid from the record's first sample (the last one partial,
    # weighted by its samples: context.Prepared.whiten_masked); laid from its last sample
    # instead (the first samples, in the long first rest, left out), every block is whole
    # and the move's end falls in other blocks: how much κ depends on where the grid falls
    data = full
    prep, base = prepared(data)
    from_end, _ = prepared(_from_sample(data, len(data) % prep.block))
    k_end = kappa(from_end, from_end.data.valid.copy())[0]
    valid = data.valid.copy()
    k_all, s_all = kappa(prep, valid)
    # the criterion's blocks (criterion.block_ids over the compared values), each left out in turn
    first = prep.compared_index(valid)
    ids = block_ids(first, prep.rest)
    t0 = data.t_s[np.flatnonzero(np.abs(data.ref_vel_mps) > 1e-6)[0]]
    left_out = []
    for b in range(int(ids.max()) + 1):
        rows = first[ids == b]
        mask = valid.copy()
        mask[rows.min():rows.max() + prep.block] = False
        end = min(rows.max() + prep.block, len(data)) - 1
        left_out.append((kappa(prep, mask)[0], data.t_s[rows.min()] - t0, data.t_s[end] - t0))
    prep.fit_mask = valid
    ks = np.array([k for k, *_ in left_out])
    worst = left_out[int(np.argmax(np.abs(ks - k_all)))]
    # the baseline residual's block means: in motion against at rest
    r = prep.blocks(np.nan_to_num(base.residual), valid)
    at_rest = prep.rest[first]
    spread = float(np.std(r[~at_rest])) / max(float(np.std(r[at_rest])), 1e-12)
    # the final error's response to a tilt of PROBE_TILT_RAD_PER_M, through estimate --model
    probe = _tilt_model_file(out, PROBE_TILT_RAD_PER_M)
    response = []
    for hint_args in ([], ["--ignore-hint"]):
        track = out / "track.csv"
        quiet(["estimate", str(rec), "--method", "smoothed", "--out", str(track), *hint_args])
        before = final_error_mm(rec, track)
        _, notes = quiet_with_notes(["estimate", str(rec), "--method", "smoothed", "--model", str(probe),
                                     "--out", str(track), *hint_args])
        moved = unsettled_mm(notes)
        response.append(f"{final_error_mm(rec, track) - before:+.1f} mm"
                        + (f" (not determined: passes differ by {moved:.1f} mm)" if moved is not None else ""))
    oracle = _hinted_response_with_reference_position(rec, PROBE_TILT_RAD_PER_M)
    moving = np.abs(data.ref_vel_mps) > 1e-6
    move_end = data.t_s[np.flatnonzero(moving)[-1]] - t0
    in_move = sum(1 for _, a, e in left_out if e > 0 and a < move_end)
    compared_to = data.t_s[min(first[-1] + prep.block, len(data)) - 1] - t0
    return (f"{rec.name.split('.')[0]}: κ {k_all:.4f} ± {s_all:.4f} rad/m (the fit's own σ); one of "
            f"{len(left_out)} blocks ({in_move} over the move, which ends at {move_end:+.2f} s; compared up to "
            f"{compared_to:+.2f} s) left out: {ks.min():.4f} … {ks.max():.4f} (most: the block "
            f"{worst[1]:+.2f} … {worst[2]:+.2f} s from the move's start: {worst[0]:.4f}); with the blocks laid from "
            f"the record's end (its first {len(full) % prep.block} samples left out): {k_end:.4f}; "
            f"baseline residual's block means in motion spread {spread:.1f}× the rests'; a tilt of "
            f"{PROBE_TILT_RAD_PER_M} rad/m moves the final error by {response[0]} hinted ({oracle:+.1f} mm with "
            f"the reference's position in place of the estimate's), {response[1]} unhinted")


ARRAY_FIELDS = ("t_s", "acc_mps2", "valid", "lost_before", "ref_pos_m", "ref_vel_mps", "ref_acc_mps2",
                "other_mps2", "temp_c", "t_host_s", "standstill_hint")


def _from_sample(data, first: int):
    """The diagnosis input without its first `first` samples."""
    from dataclasses import replace

    return replace(data, **{f: getattr(data, f)[first:] for f in ARRAY_FIELDS if getattr(data, f) is not None})


def _hinted_response_with_reference_position(rec: Path, tilt_rad_per_m: float) -> float:
    """How far the hinted final error moves when the tilt is corrected with the reference's
    position (what the diagnosis fitted it with) instead of the estimate's: whether the
    position used explains what the compensation does."""
    from gateway.commands.estimate import settings_for
    from gateway.core.estimator import estimate_series
    from gateway.core.model_compensation import ModelTerm, SampleContext, SensorModel, compensate

    raw = read_recording(rec)
    series = to_acceleration(raw)
    settings = settings_for(series, raw.form, "auto", None)
    pos = series.reference["ref_pos_m"] - series.reference["ref_pos_m"][0]
    acc = np.asarray(series.acc_mps2, dtype=float)
    model = SensorModel((ModelTerm("tilt", {"tilt_gradient_rad_per_m": tilt_rad_per_m}),))
    final = []
    for a in (acc, compensate(model, acc, SampleContext(series.t_s, pos_m=pos))):
        track = estimate_series(series.t_s, a, series.valid, method="smoothed", settings=settings,
                                standstill_hint=series.standstill_hint)
        final.append(float(track.pos_m[-1]))
    return (final[1] - final[0]) * 1e3


def _tilt_model_file(out: Path, tilt_rad_per_m: float) -> Path:
    """A model file with one tilt term, as `diagnose --model-out` writes it."""
    path = out / f"tilt_{tilt_rad_per_m:+.4f}.model.json"
    path.write_text(json.dumps({"format": "adxlgw-sensor-model", "version": 1, "source": "a tilt given",
                                "effects": [{"name": "tilt", "params": {"tilt_gradient_rad_per_m": tilt_rad_per_m}}]}))
    return path


# one tilt for the whole run, tried on every file: the range the files' own fits span
# (0.02-0.03 rad/m as the diagnosis fits, 0.005-0.02 with the grid laid from the end) and
# its sign reversed: the best any joint fit of one kappa could give
COMMON_TILTS_RAD_PER_M = (-0.01, 0.0025, 0.005, 0.01, 0.02, 0.03)


def common_tilt_table(recs: dict, out: Path) -> None:
    """The hinted final error of every file with one tilt for the run: how many files a
    single kappa, however it were fitted, improves."""
    print()
    print("one tilt for the run, applied to every file: final error, mm (hinted, as adxlgw estimate runs)")
    print(" | ".join(["κ (rad/m)"] + [n.split("_y605")[0] for n in recs] + ["files improved"]))
    print(" | ".join("---" for _ in range(len(recs) + 2)))
    base = {}
    for name, rec in recs.items():
        track = out / "track.csv"
        quiet(["estimate", str(rec), "--method", "smoothed", "--out", str(track)])
        base[name] = final_error_mm(rec, track)
    print(" | ".join(["0 (no model)"] + [f"{v:+.1f}" for v in base.values()] + ["–"]))
    for kappa in COMMON_TILTS_RAD_PER_M:
        model = _tilt_model_file(out, kappa)
        row, improved = [f"{kappa:g}"], 0
        for name, rec in recs.items():
            track = out / "track.csv"
            _, notes = quiet_with_notes(["estimate", str(rec), "--method", "smoothed", "--model", str(model),
                                         "--out", str(track)])
            err = final_error_mm(rec, track)
            moved = unsettled_mm(notes)
            row.append(with_model_cell(err, moved))
            gain = predictive_gain_mm(base[name], err, moved)
            improved += int(gain is not None and gain > 0)
        print(" | ".join(row + [f"{improved} of {len(recs)}"]))


def _error_table(recs: dict, models: dict, out: Path, hinted: bool) -> None:
    """The final errors without and with each sensor's model, and the predictive gains."""
    hint_args = [] if hinted else ["--ignore-hint"]
    print()
    print("final position error after the 605 mm move, mm (smoothed estimate, "
          + ("the recording's standstill hint used, as adxlgw estimate does by default"
             if hinted else "--ignore-hint: the estimator finds its own rests") + "); columns: the model fitted on")
    head = ["applied to", "no model"] + [f"{m.split('_')[0]}_{m.split('_')[1]}" for m in models]
    print(" | ".join(head))
    print(" | ".join("---" for _ in head))
    gains = {}
    for name, rec in recs.items():
        row = [name]
        track = out / "track.csv"
        quiet(["estimate", str(rec), "--method", "smoothed", "--out", str(track), *hint_args])
        base = final_error_mm(rec, track)
        row.append(f"{base:+.1f}")
        for fit_on, m_json in models.items():
            _, notes = quiet_with_notes(["estimate", str(rec), "--method", "smoothed", "--model", str(m_json),
                                         "--out", str(track), *hint_args])
            err = final_error_mm(rec, track)
            moved = unsettled_mm(notes)
            row.append(with_model_cell(err, moved, own=fit_on == name))
            if fit_on != name:
                gains.setdefault(name, []).append(predictive_gain_mm(base, err, moved))
        print(" | ".join(row))
    print()
    verdicts = {}
    for name, g in gains.items():
        known = [x for x in g if x is not None]
        verdicts[name] = median_is_positive(g)
        print(f"{name}: predictive gain (|error| without − with, models of the other sensors): "
              + (f"median {np.median(g):+.1f} mm, worst {min(g):+.1f} mm" if len(known) == len(g) else
                 f"determined {', '.join(f'{x:+.1f}' for x in known) or 'none'} mm, {len(g) - len(known)} of "
                 f"{len(g)} not determined (passes did not settle)") + f": median > 0 {verdicts[name]}")
    counts = {v: sum(x == v for x in verdicts.values()) for v in ("yes", "no", "not determined")}
    print(f"files with a positive median predictive gain ({'hinted' if hinted else 'unhinted'}): "
          f"{counts['yes']} of {len(verdicts)} (no: {counts['no']}, not determined: {counts['not determined']})")


def median_is_positive(gains: list) -> str:
    """'yes', 'no' or 'not determined': whether the median of the gains is above zero when
    some are unknown (None, a correction that did not settle): decided only where every
    value the unknown ones could take gives the same answer (their extremes do)."""
    def median_with(fill: float) -> float:
        return float(np.median([fill if x is None else x for x in gains]))

    lowest, highest = median_with(-1e12), median_with(1e12)
    if lowest > 0:
        return "yes"
    if highest <= 0:
        return "no"
    return "not determined"

if __name__ == "__main__":
    sys.exit(main())
