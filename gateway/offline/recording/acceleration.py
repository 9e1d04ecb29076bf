"""A recording in SI units: sample time and acceleration along the measured axis, from
either form, whole or chunk by chunk, with what reading found wrong on the way."""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from gateway.core.chunked_conversion import RawChunkConverter, SequenceReport
from gateway.core.conversion import Calibration
from gateway.core.sensor_model import SensorParams
from gateway.errors import RecordingError
from gateway.offline.recording.format import HINT_COLUMN, REFERENCE_COLUMNS, Recording, calibration_from
from gateway.offline.recording.sources import RecordingSource

# the acceleration form's plausibility limit when the file does not state its sensor's
# range (metadata acc_range_mps2): beyond ~100 g no accelerometer this format is meant
# for (robot arms, vehicles) reads; a 1e300 sample is not a measurement
DEFAULT_ACC_RANGE_MPS2 = 1000.0


@dataclass
class InputReport:
    """What reading found wrong but could carry on past: said to the user, never hidden."""

    sequence: SequenceReport = field(default_factory=SequenceReport)
    impossible: int = 0  # samples beyond the sensor's possible range: flagged invalid
    impossible_limit_mps2: float = math.inf

    def warnings(self) -> list[str]:
        out = self.sequence.problems()
        if self.impossible:
            out.append(f"{self.impossible} samples beyond ±{self.impossible_limit_mps2:.4g} m/s² (physically "
                       "impossible for the sensor): flagged invalid, not integrated")
        return out


@dataclass
class AccelerationSeries:
    """What the estimators read: sample times and acceleration along the measured axis."""

    t_s: np.ndarray
    acc_mps2: np.ndarray  # along the axis the reference refers to; NaN where invalid
    valid: np.ndarray
    lost_before: np.ndarray
    other_axis_mps2: np.ndarray | None = None
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    temp_c: np.ndarray | None = None
    t_host_s: np.ndarray | None = None
    axis: str = "x"
    report: InputReport = field(default_factory=InputReport)
    standstill_hint: np.ndarray | None = None  # 1 at rest, 0 moving, NaN unknown

    def __len__(self) -> int:
        return self.t_s.size

    def from_time(self, t0_s: float, ref_origin_m: float = 0.0) -> AccelerationSeries:
        """The rows at or after t0_s (e.g. a sensor's settling at power-up left out), the
        reference position measured from ref_origin_m (where the estimate begins)."""
        keep = self.t_s >= t0_s
        reference = {k: v[keep] for k, v in self.reference.items()}
        if "ref_pos_m" in reference:
            reference["ref_pos_m"] = reference["ref_pos_m"] - ref_origin_m

        def cut(x):
            return None if x is None else x[keep]

        return AccelerationSeries(self.t_s[keep], self.acc_mps2[keep], self.valid[keep], self.lost_before[keep],
                                  cut(self.other_axis_mps2), reference, cut(self.temp_c), cut(self.t_host_s),
                                  self.axis, self.report, cut(self.standstill_hint))


def _axis_of(path: str, metadata: dict[str, str]) -> str:
    axis = metadata.get("axis", "x").strip().lower()
    if axis not in ("x", "y"):
        raise RecordingError(f"{path}: metadata axis={axis!r} must be 'x' or 'y'")
    return axis


def _acc_range_mps2(path: str, metadata: dict[str, str]) -> float:
    text = metadata.get("acc_range_mps2")
    if text is None:
        return DEFAULT_ACC_RANGE_MPS2
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise RecordingError(f"{path}: metadata acc_range_mps2={text!r} is not a positive number")
    return value


class AccelerationConverter:
    """Either form's chunks → AccelerationSeries chunks, with what carries between them."""

    def __init__(self, path: str, form: str, metadata: dict[str, str], calibration: Calibration | None = None):
        self.path = path
        self.form = form
        self.axis = _axis_of(path, metadata)
        self.report = InputReport()
        if form == "raw":
            self._raw = RawChunkConverter(float(metadata["tick_hz"]), calibration or calibration_from(path, metadata),
                                          SensorParams().range_g)
            self.report.sequence = self._raw.report
            self.report.impossible_limit_mps2 = self._raw.limit_mps2
        else:
            self._limit = _acc_range_mps2(path, metadata)
            self.report.impossible_limit_mps2 = self._limit

    def convert(self, c: dict[str, np.ndarray]) -> AccelerationSeries:
        main, other = ("x", "y") if self.axis == "x" else ("y", "x")
        if self.form == "raw":
            flags = (np.nan_to_num(c["flags"], nan=0.0).astype(np.int64) if "flags" in c
                     else np.zeros(c["seq"].size, np.int64))
            try:
                ch = self._raw.convert(c["seq"].astype(np.int64), c["t1x"], c["t1y"], c["t2"], flags)
            except ValueError as err:
                raise RecordingError(f"{self.path}: {err}") from err
            self.report.impossible += ch.impossible[main]
            t_s, lost = ch.t_s, ch.lost_before
            acc_main, acc_other, valid_main = ch.acc_mps2[main], ch.acc_mps2[other], ch.valid[main]
        else:
            t_s = c["t_s"]
            lost = np.zeros(t_s.size, dtype=np.int64)
            acc_main = c["acc_x_mps2"] if self.axis == "x" or "acc_y_mps2" not in c else c["acc_y_mps2"]
            acc_other = c.get("acc_y_mps2") if self.axis == "x" else c.get("acc_x_mps2")
            finite = np.isfinite(acc_main)
            valid_main = finite & (np.abs(acc_main) <= self._limit)
            self.report.impossible += int(np.count_nonzero(finite & ~valid_main))
            if acc_other is not None:
                acc_other = np.where(np.abs(acc_other) <= self._limit, acc_other, np.nan)
        reference = {k: c[k] for k in REFERENCE_COLUMNS if k in c}
        return AccelerationSeries(
            t_s=t_s,
            acc_mps2=np.where(valid_main, acc_main, np.nan),
            valid=valid_main,
            lost_before=lost,
            other_axis_mps2=acc_other,
            reference=reference,
            temp_c=c.get("temp_c"),
            t_host_s=c.get("t_host_s"),
            axis=self.axis,
            report=self.report,
            standstill_hint=c.get(HINT_COLUMN),
        )


def to_acceleration(rec: Recording, calibration: Calibration | None = None) -> AccelerationSeries:
    """Either form → sample time and acceleration along the measured axis."""
    series = AccelerationConverter(rec.path, rec.form, rec.metadata, calibration).convert(rec.columns)
    # a reference column that is empty throughout is not a reference
    series.reference = {k: v for k, v in series.reference.items() if rec.has(k)}
    return series


def acceleration_chunks(source: RecordingSource, columns: list[str] | None = None, progress=None,
                        calibration: Calibration | None = None) -> Iterator[AccelerationSeries]:
    """The recording as AccelerationSeries chunks (the streamed commands); each chunk's
    report is the running one, complete after the last chunk."""
    conv = AccelerationConverter(source.path, source.form, source.metadata, calibration)
    chunks = source.chunks(columns, progress=progress)
    try:
        for chunk in chunks:
            yield conv.convert(chunk)
    finally:
        # now, not whenever the garbage collector gets to it: a reader left suspended
        # until interpreter exit can abort the process in pyarrow's teardown (exit 134)
        chunks.close()

