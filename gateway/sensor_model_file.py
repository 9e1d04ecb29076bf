"""The extended sensor model as a file: written by `adxlgw diagnose --model-out`, read by
`adxlgw estimate --model` and by the daemon ([model] file); applied by
gateway/core/model_compensation.py."""
from __future__ import annotations

import json

from gateway.core.model_compensation import ModelError, SensorModel, check_terms, model_from_dict
from gateway.errors import InputError


def load_sensor_model(path: str) -> SensorModel:
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    except json.JSONDecodeError as err:
        raise InputError(f"{path}: line {err.lineno}: not JSON: {err.msg}") from err
    try:
        model = model_from_dict(doc, path)
        check_terms(model, path)
    except ModelError as err:
        raise InputError(str(err)) from err
    return model


def write_sensor_model(path: str, model: SensorModel) -> None:
    try:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(model.to_dict(), fh, indent=2, allow_nan=False, ensure_ascii=False)
            fh.write("\n")
    except OSError as err:
        raise InputError(f"{path}: cannot write: {err.strerror or err}") from err
