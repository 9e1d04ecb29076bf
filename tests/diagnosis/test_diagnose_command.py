"""`adxlgw diagnose`: the command on real parts — simulated recordings, a hidden effect, bad input."""
import json

import numpy as np
import pytest

from gateway.cli import main
from gateway.core.diagnosis import SETUP_PROPERTIES
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_effects import ScaleFactorTerm
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.offline.recording import write_recording
from gateway.sensor_model_file import load_sensor_model

EFFECTS = ["scale_factor", "tilt", "cross_axis", "temperature_offset", "timing", "sample_loss", "vibration",
           "bandwidth", "nonlinearity", "clipping", "bias_random_walk", "reference_delay", "motion_offset",
           "cross_talk"]
PNGS = ("residual.png", "spectrum.png", "allan.png", "position.png")


def _strict_json(path):
    def no_constants(name):
        raise AssertionError(f"{path}: {name} is not JSON")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=no_constants)


def _write_sim(path, seed, terms=()):
    sim = simulate(build_profile(ScenarioSettings(name="paper", strokes=StrokeSettings(strokes=3))),
                   SensorParams(), seed=seed, error_terms=terms)
    write_recording(path, {"tick_hz": f"{sim.tick_hz:g}", "source": "simulation", "axis": "x", "seed": str(seed)},
                    sim.recording_columns())
    return path


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    path = tmp_path_factory.mktemp("clean") / "clean.csv"
    assert main(["simulate", "--scenario", "paper", "--strokes", "3", "--seed", "5", "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def clean_run(clean, tmp_path_factory):
    out = tmp_path_factory.mktemp("clean_out")
    # --model-with asks for a candidate the clean record does not name: it is fitted anyway
    code = main(["diagnose", str(clean), "--json", str(out / "d.json"), "--report", str(out / "rep"),
                 "--model-out", str(out / "m.json"), "--model-with", "tilt"])
    return code, out


def test_list_effects_names_all_fourteen_with_a_summary(capsys):
    assert main(["diagnose", "--list-effects"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    names = [line.split()[0] for line in lines]
    assert sorted(names) == sorted(EFFECTS)
    assert all(len(line.split(None, 1)) == 2 for line in lines)  # each with its summary


def test_without_file_or_list_effects_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["diagnose"])
    assert exc.value.code == 2
    assert "usage:" in capsys.readouterr().err


def test_clean_recording_finds_nothing_and_writes_strict_json(clean_run):
    code, out = clean_run
    assert code == 0
    doc = _strict_json(out / "d.json")
    for key in ("effects", "residual_white", "unexplained", "candidates", "cannot_analyse", "screening"):
        assert key in doc
    assert doc["effects"] == []
    assert doc["reference"] == "recorded"
    assert doc["residual_white"] is True and doc["unexplained"] is False
    # every effect, and the setup's own properties fitted beside them (never named)
    assert sorted(c["name"] for c in doc["candidates"]) == sorted([*EFFECTS, *SETUP_PROPERTIES])
    assert SETUP_PROPERTIES == ("output_filter", "reading_instant")


def test_model_with_writes_an_unnamed_candidate_with_its_fitted_parameters(clean_run):
    code, out = clean_run
    assert code == 0
    model = load_sensor_model(str(out / "m.json"))
    assert [t.name for t in model.terms] == ["tilt"]
    (kappa,) = model.terms[0].params.values()
    assert np.isfinite(kappa) and abs(kappa) < 0.5  # fitted on a clean record: small, not the range's edge
    assert any(note.startswith("tilt: added by --model-with; the diagnosis did not name it") for note in model.notes)


def test_a_fit_no_part_can_have_is_listed_as_not_physical(tmp_path):
    # a 30 % scale error: predictive, but beyond the data sheet's range (|s| <= 20 %); the
    # report lists the shape under not_physical ("look elsewhere") and names nothing of it
    rec = _write_sim(tmp_path / "scale30.csv", seed=5, terms=(ScaleFactorTerm(0.30),))
    out = tmp_path / "scale30.json"
    assert main(["diagnose", str(rec), "--json", str(out)]) == 0
    doc = _strict_json(out)
    status = {c["name"]: c["status"] for c in doc["candidates"]}
    assert status["scale_factor"] == "not physical"
    assert "scale_factor" in [n["shape"] for n in doc["not_physical"]]
    assert "scale_factor" not in [e["name"] for e in doc["effects"]]


def test_report_writes_markdown_and_png_plots(clean_run):
    code, out = clean_run
    assert code == 0
    rep = out / "rep"
    md = (rep / "report.md").read_text(encoding="utf-8")
    assert "residual white: yes; unexplained structure remains: no" in md
    for name in PNGS:
        data = (rep / name).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > 1000, name
        assert f"]({name})" in md


def test_summary_on_stdout_and_progress_on_stderr(clean, capsys):
    assert main(["diagnose", str(clean)]) == 0
    cap = capsys.readouterr()
    assert "reference: recorded" in cap.out
    assert "effects found: none" in cap.out
    assert "residual white: yes; unexplained structure remains: no" in cap.out
    for name in EFFECTS:
        assert name in cap.out
    assert "diagnose: baseline" in cap.err
    assert all(line.startswith(("diagnose: ", "adxlgw diagnose: warning: ")) for line in cap.err.splitlines())


def test_hidden_scale_factor_is_named_with_its_value_and_gain(tmp_path, capsys):
    rec = _write_sim(tmp_path / "scale.csv", seed=5, terms=(ScaleFactorTerm(0.02),))
    out = tmp_path / "scale.json"
    assert main(["diagnose", str(rec), "--json", str(out)]) == 0
    doc = _strict_json(out)
    names = [e["name"] for e in doc["effects"]]
    assert "scale_factor" in names
    effect = doc["effects"][names.index("scale_factor")]
    value, std = effect["params"]["scale_error_frac"]
    assert abs(value - 0.02) < 0.003 and std > 0
    gain = effect["gain"]
    assert gain["residual_rms_mps2"][1] < gain["residual_rms_mps2"][0]
    assert gain["distance"]["available"] is True
    assert gain["distance"]["improvement_mm"] > 0
    text = capsys.readouterr().out
    assert "scale_factor (signal): scale_error_frac = " in text
    assert "distance error (stop_rms_mm)" in text


def _one_line_error(capsys, path):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("adxlgw diagnose: error: ") and str(path) in err[0]
    return err[0]


def test_too_short_recording_is_bad_input(clean, tmp_path, capsys):
    lines = clean.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[: header + 1 + 50]) + "\n")
    assert main(["diagnose", str(short)]) == 2
    assert "nothing to analyse" in _one_line_error(capsys, short)


def test_non_numeric_cell_is_bad_input(clean, tmp_path, capsys):
    lines = clean.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    cells = lines[header + 10].split(",")
    cells[1] = "abc"
    lines[header + 10] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    assert main(["diagnose", str(bad)]) == 2
    assert "'abc' is not a number" in _one_line_error(capsys, bad)


def test_header_only_file_is_bad_input(clean, tmp_path, capsys):
    lines = clean.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    empty = tmp_path / "empty.csv"
    empty.write_text("\n".join(lines[: header + 1]) + "\n")
    assert main(["diagnose", str(empty)]) == 2
    _one_line_error(capsys, empty)


def test_no_reference_and_no_standstill_is_bad_input(tmp_path, capsys):
    rng = np.random.default_rng(11)
    t = np.arange(3000) * 1e-3
    # still for 0.22 s (shorter than the 0.2 s rest plus its guard), then shaken to the end
    acc = np.where(t < 0.22, 0.0, 8.0 * np.sin(2 * np.pi * 3.1 * t) + 5.0 * np.sin(2 * np.pi * 11.0 * t))
    acc = acc + 0.05 * rng.standard_normal(t.size)
    path = tmp_path / "moving.csv"
    write_recording(path, {"source": "test", "axis": "x"}, {"t_s": t, "acc_x_mps2": acc})
    assert main(["diagnose", str(path)]) == 2
    assert "no reference motion and no standstill" in _one_line_error(capsys, path)


def _without_columns(clean, tmp_path, drop):
    lines = clean.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    names = lines[header].split(",")
    keep = [i for i, n in enumerate(names) if n not in drop]
    partial = tmp_path / "partial.csv"
    partial.write_text("\n".join(lines[:header] + [",".join(line.split(",")[i] for i in keep)
                                                    for line in lines[header:]]) + "\n")
    return partial


def test_a_position_only_reference_is_used_with_what_it_lacks_derived(clean, tmp_path, capsys):
    partial = _without_columns(clean, tmp_path, ("ref_vel_mps", "ref_acc_mps2"))
    out = tmp_path / "partial.json"
    assert main(["diagnose", str(partial), "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "adxlgw diagnose: warning: reference without ref_vel_mps, ref_acc_mps2: derived from the position" in err
    doc = _strict_json(out)
    assert doc["reference"] == "recorded"
    assert doc["effects"] == [], doc["effects"]
    scale = next(c for c in doc["candidates"] if c["name"] == "scale_factor")
    assert scale["status"] != "not applicable"


def test_a_reference_without_position_is_said_and_not_used(clean, tmp_path, capsys):
    partial = _without_columns(clean, tmp_path, ("ref_pos_m",))
    out = tmp_path / "partial.json"
    assert main(["diagnose", str(partial), "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "adxlgw diagnose: warning: reference incomplete" in err
    doc = _strict_json(out)
    assert doc["reference"] == "estimated"
    assert any("reference incomplete" in c for c in doc["cannot_analyse"])


def test_cross_axis_is_looked_for_only_when_the_other_axis_is_said_to_be_still(clean, tmp_path, capsys):
    out = tmp_path / "d.json"
    assert main(["diagnose", str(clean), "--json", str(out)]) == 0
    cross = next(c for c in _strict_json(out)["candidates"] if c["name"] == "cross_axis")
    assert cross["status"] == "not applicable" and "--other-axis-still" in cross["reason"]
    assert main(["diagnose", str(clean), "--other-axis-still", "--json", str(out)]) == 0
    cross = next(c for c in _strict_json(out)["candidates"] if c["name"] == "cross_axis")
    assert cross["status"] == "rejected"


def test_a_reference_block_below_one_is_bad_input(clean, capsys):
    assert main(["diagnose", str(clean), "--reference-block", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("--reference-block 0: must be a whole number of samples ≥ 1")
