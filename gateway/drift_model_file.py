"""The fitted zero-drift model as a file: written by `adxlgw fit-drift --model-out`,
read by `adxlgw estimate --drift-model` and by the daemon ([estimator] drift_model)."""
from __future__ import annotations

import json

from gateway.core.drift_fit import FittedDrift
from gateway.errors import InputError


def load_drift_model(path: str) -> FittedDrift:
    try:
        with open(path, encoding="utf-8") as fh:
            return FittedDrift.from_dict(json.load(fh))
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path}: not a drift model written by 'adxlgw fit-drift --model-out' ({err})") from err
