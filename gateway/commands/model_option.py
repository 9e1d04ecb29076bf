"""`--model M.json` for the offline estimate: the extended sensor model a diagnosis wrote
(`adxlgw diagnose --model-out`), applied by gateway/core/model_compensation.py."""
from __future__ import annotations

import argparse

import numpy as np

from gateway.core.model_compensation import SampleContext, compensated_estimate, settings_with_model_lag
from gateway.core.sensor_model import SensorParams
from gateway.sensor_model_file import load_sensor_model


def add_model_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", metavar="M.json",
                   help="correct the measurement with the extended sensor model written by "
                        "adxlgw diagnose --model-out (docs/diagnosis.md, 'The model, used')")


def estimate_with_model(path: str, series, settings, form: str, run):
    """(track, notes): run(acc, settings) on the acceleration the model corrects; terms
    that need the estimate (position, motion) are iterated with it."""
    model = load_sensor_model(path)
    notes = []
    if settings is not None:
        nominal = SensorParams().bandwidth_hz if form == "raw" else None
        settings = settings_with_model_lag(settings, model, nominal)
    rest = series.standstill_hint > 0.5 if series.standstill_hint is not None else None
    ctx = SampleContext(series.t_s, series.other_axis_mps2, series.temp_c, rest=rest)
    result = compensated_estimate(model, np.asarray(series.acc_mps2, float), ctx, lambda acc: run(acc, settings))
    names = ", ".join(t.name for t in model.terms) or "no terms"
    passes = result.describe()
    notes.append(f"model {path}: {names}" + (f" ({passes})" if passes else "")
                 + (f"; not compensated: {', '.join(model.not_compensated)}" if model.not_compensated else ""))
    return result.track, notes
