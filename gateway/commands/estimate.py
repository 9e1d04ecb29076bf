"""adxlgw estimate: position and velocity from a recording, by one of five methods."""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from gateway.commands.model_option import add_model_argument, estimate_with_model
from gateway.config import travel_problem
from gateway.core.drift_fit import FittedDrift
from gateway.core.estimator import COMPARED_METHODS, METHODS, EstimateTrack, estimate_series
from gateway.core.estimator_settings import EstimatorSettings, from_rest, from_sensor_model
from gateway.core.estimator_stream import RealtimeChunks
from gateway.core.evaluation import ErrorSummary, summarise_errors
from gateway.core.evaluation_stream import StreamedErrors
from gateway.core.reference_point import NoRestError, find_initial_rest, quiet_part
from gateway.core.retiming import RetimingError, retime
from gateway.core.sensor_model import SensorParams
from gateway.drift_model_file import load_drift_model
from gateway.errors import InputError, RecordingError
from gateway.offline.figures import check_plot_path, save_figure
from gateway.offline.progress import progress_bar, reading_bar
from gateway.offline.recording import (
    AccelerationSeries,
    ColumnWriter,
    RecordingSource,
    acceleration_chunks,
    check_fits_in_memory,
    open_recording,
    read_all,
    to_acceleration,
)

# Memory of the smoothed estimate per sample, bytes: the recording's columns and the
# series, the forward pass's states kept for the backward pass (~90), the output columns
# and what writing them takes. Measured: 266 (peak RSS 5.75 GB for 21.6 M samples,
# benchmarks/speed/offline_scale.py, docs/estimation.md), rounded up; plus ~42 when the stops
# are decided from both ends (estimator_passes.stops_seen_from_the_end: the one-pass answer
# kept beside the second pass, the derived hint) — not measured at 12 h, counted; plus
# up to 48 (an index and 5 floats) for the soft hinted velocity updates' records
# (kernel_update.soft_update_bound: at most one per hinted sample, reached only by a
# hint that toggles once per window) — counted, the worst case, not measured.
SMOOTHED_BYTES_PER_SAMPLE = 360
# Memory of the zupt estimate per sample, bytes: the recording's columns, the series and the
# output as for smoothed (~270), plus the smoother's stored predictions and posteriors (24
# floats, 192 bytes) and a second set when the record does not end at rest (zupt_smoother).
# Counted from the code, not measured.
ZUPT_BYTES_PER_SAMPLE = 270 + 2 * 192
# the methods that take the filter's settings (noise from the sensor model or the rest)
FILTER_METHODS = ("realtime", "smoothed", "zupt", "zupt-forward")
# the estimate's columns written as integers
TRACK_INTEGER_COLUMNS = ("standstill", "flags")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "estimate",
        help="estimate position and velocity from a recording",
        description="Estimate position, velocity and acceleration for every sample of a recording and "
                    "write them with the health columns. raw: plain double integration (paper fig. 6); "
                    "paper: reference-point compensation + the paper's Kalman filter (fig. 7); "
                    "realtime: the gateway's causal filter (bias state, standstill detection, ZUPT/ZARU); "
                    "smoothed: the same with a backward pass; zupt: an offline smoother that finds the rests "
                    "in the accelerometer's own quiet stretches, decides each from both ends, and applies "
                    "zero-velocity updates with a bias state and a backward pass (the machine's hint only "
                    "vetoes a rest); zupt-forward: the same with each rest decided from its start alone and "
                    "no backward pass (what a realtime estimator with that detector would give). Where the "
                    "recording has reference columns "
                    "the errors are printed (final, at each stop, RMS).",
    )
    p.add_argument("recording", metavar="FILE.csv", help="the recording: CSV, or Parquet (.parquet)")
    p.add_argument("--method", choices=METHODS + COMPARED_METHODS, default="realtime",
                   help="estimation method (default: realtime)")
    p.add_argument("--out", required=True, help="output: t_s, pos_m, vel_mps, acc_mps2 and health columns; "
                                                "CSV, or Parquet when it ends in .parquet")
    add_model_argument(p)
    p.add_argument("--plot", metavar="FILE.png", help="draw the estimate against the reference")
    p.add_argument("--noise-from", choices=("auto", "sensor", "rest"), default="auto",
                   help="where the filter's noise settings come from: the ADXL202 sensor model, or the "
                        "recording's own initial rest (auto: sensor for the raw form, rest for the "
                        "acceleration form, i.e. another sensor)")
    p.add_argument("--drift-model", metavar="DRIFT.json",
                   help="fitted drift and noise (adxlgw fit-drift --model-out) instead of the data-sheet values")
    p.add_argument("--ignore-hint", action="store_true",
                   help="do not use the recording's standstill_hint column (the machine's 'at rest' / "
                        "'moving'; realtime, smoothed and zupt use it when present)")
    p.add_argument("--skip-s", type=_seconds, default=0.0, metavar="SECONDS",
                   help="leave out the recording's first SECONDS (e.g. a sensor settling at power-up, a "
                        "logger's first rows); the estimate and the reference's position begin after them")
    p.add_argument("--travel-m", type=float, nargs=2, metavar=("LOWEST", "HIGHEST"),
                   help="the axis's travel in m from the start (its soft limits), as the daemon's "
                        "estimator.travel_m: with the velocity lost, a quiet stretch is a stop only once it "
                        "outlasts a cruise at the speed floor across it (default: the daemon's ±10 m)")
    p.add_argument("--returns-to-start", action="store_true",
                   help="the motion ends where it began (net displacement zero): print the final position as its error")
    p.set_defaults(run=run)


def with_travel(settings: EstimatorSettings, args: argparse.Namespace) -> EstimatorSettings:
    """The settings with the axis's travel from --travel-m (checked as the daemon's config is)."""
    travel_m = getattr(args, "travel_m", None)
    if travel_m is None:
        return settings
    problem = travel_problem(travel_m)
    if problem:
        raise InputError(f"--travel-m {travel_m[0]:g} {travel_m[1]:g}: {problem}")
    return replace(settings, travel_span_m=travel_m[1] - travel_m[0])


def _seconds(text: str) -> float:
    """A duration ≥ 0 from the command line (a wrong one: argparse's one line, exit 2)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration in seconds (a number ≥ 0)")
    return value


class Skip:
    """--skip-s over a recording read whole or chunk by chunk: the rows before the first
    row's time + skip_s left out, the reference position measured from its value at the
    first row kept (where the estimate begins)."""

    def __init__(self, skip_s: float):
        self.skip_s = skip_s
        self.until_s: float | None = None
        self.ref_origin_m: float | None = None

    def __call__(self, series: AccelerationSeries) -> AccelerationSeries:
        if not self.skip_s or not len(series):
            return series
        if self.until_s is None:
            self.until_s = float(series.t_s[0]) + self.skip_s
        if self.ref_origin_m is None:
            kept = series.t_s >= self.until_s
            ref = series.reference.get("ref_pos_m")
            if not kept.any():
                return series.from_time(self.until_s)
            self.ref_origin_m = float(ref[kept][0]) if ref is not None else 0.0
        return series.from_time(self.until_s, self.ref_origin_m)


# a rest that ends this soon after the first sample may be a sensor settling at power-up
SETTLING_S = 0.1


def _no_rest(args: argparse.Namespace, err: NoRestError) -> InputError:
    """The one-line refusal; where the motion seems to begin at the very first samples, the
    way out for a sensor that settles there."""
    hint = ""
    if args.skip_s == 0.0 and err.moves_after_s is not None and err.moves_after_s < SETTLING_S:
        hint = ("; if the first samples are the sensor settling at power-up (not motion), --skip-s "
                "SECONDS leaves them out")
    return InputError(f"{args.recording}: cannot estimate ({args.method}): {err}{hint}")


# rows of the time axis judged at a time (the re-timing's memory stays bounded on a 12-hour file)
TIME_CHECK_ROWS = 1 << 17


def check_time_axis(path: str, t_s: np.ndarray) -> None:
    """Refuse a time axis that is a logger's arrival times: the filter integrates over the
    times it is given, and a bursty or backlogged axis makes every stop's velocity wrong
    with nothing in the samples to show it (confidently wrong). Judged by the importer's
    re-timing (gateway/core/retiming.py, written once): runs of rows arriving less than half
    a sensor period apart (bursts), or a backlog flushed faster than the sensor samples. A
    sample clock's jitter makes neither. The way out is named: `adxlgw import --arrival-col`
    re-times such an axis onto the sensor's regular clock."""
    for start in range(0, t_s.size, TIME_CHECK_ROWS):
        block = t_s[start:start + TIME_CHECK_ROWS]
        try:
            r = retime(block)
        except RetimingError:  # too short, or times that do not advance: the filter flags those
            continue
        flushed = [e for e in r.late if e.arrival_interval_s < 0.5 * r.period_s]
        if r.bursts >= 3 or flushed:
            what = (f"{r.bursts} bursts of rows less than half a period ({r.period_s * 1e3:.3g} ms) apart"
                    if r.bursts >= 3 else f"a backlog flushed at {flushed[0].arrival_interval_s * 1e3:.3g} ms "
                                          f"spacing (rows {start + flushed[0].start}–{start + flushed[0].stop - 1})")
            raise InputError(f"{path}: the time axis shows {what}: these are arrival times, not sample times — "
                             "re-time them with 'adxlgw import --arrival-col' first")


def settings_for(series: AccelerationSeries, form: str, noise_from: str,
                 drift: FittedDrift | None) -> EstimatorSettings:
    """The filter's settings for this recording (see estimator_settings for each source)."""
    source = noise_from if noise_from != "auto" else ("sensor" if form == "raw" else "rest")
    if source == "sensor":
        return from_sensor_model(SensorParams(), drift_fit=drift, axis=series.axis)
    if drift is not None:
        raise InputError("--drift-model describes the ADXL202; it cannot be combined with noise from the rest")
    if len(series) < 2:  # the streamed estimate's first chunk: a file of one row
        raise NoRestError(f"only {len(series)} sample: no sample period, no rest to measure the noise on")
    period = float(np.median(np.diff(series.t_s)))
    # the noise is measured where the rest is quiet on its own noise's scale (quiet_part)
    rest = quiet_part(series.acc_mps2, series.valid, find_initial_rest(series.acc_mps2, series.valid, period),
                      period)
    try:
        return from_rest(series.acc_mps2[rest.start:rest.stop], period)
    except ValueError as err:  # e.g. a noise-free rest: a rest, but no noise to set the filter from
        raise NoRestError(f"the initial rest (samples {rest.start}–{rest.stop - 1}) cannot give the noise "
                          f"settings: {err}") from err


def track_writer(path: str, track: EstimateTrack) -> ColumnWriter:
    """The output file for tracks like this one (CSV or Parquet by extension), written atomically."""
    return ColumnWriter(path, list(track.columns()), None, integer_columns=TRACK_INTEGER_COLUMNS)


def write_track(path: str, track: EstimateTrack) -> None:
    chunk = 1 << 20
    cols = track.columns()
    with track_writer(path, track) as w, progress_bar(len(track), f"writing {path}", " rows") as bar:
        for start in range(0, max(len(track), 1), chunk):
            w.write({n: c[start:start + chunk] for n, c in cols.items()})
            bar.update(min(chunk, len(track) - start))


def plot_track(path: str, track: EstimateTrack, reference: dict, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = track.t_s
    has_ref = "ref_pos_m" in reference
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    still = track.standstill
    for ax in axes:
        ax.fill_between(t, 0, 1, where=still, transform=ax.get_xaxis_transform(), color="0.9", lw=0,
                        label="standstill (detected)")
    axes[0].plot(t, track.pos_m, label=f"estimate ({track.method})")
    axes[1].plot(t, track.vel_mps, label=f"estimate ({track.method})")
    if has_ref:
        axes[0].plot(t, reference["ref_pos_m"], "k--", lw=1, label="reference")
        if "ref_vel_mps" in reference:
            axes[1].plot(t, reference["ref_vel_mps"], "k--", lw=1, label="reference")
        err = track.pos_m - reference["ref_pos_m"]
        axes[2].plot(t, err * 1e3, label="position error")
        axes[2].fill_between(t, -2e3 * track.pos_std_m, 2e3 * track.pos_std_m, alpha=0.3, label="±2σ (filter)")
        axes[2].set_ylabel("error (mm)")
    else:
        axes[2].plot(t, track.bias_mps2, label="bias estimate")
        axes[2].set_ylabel("bias (m/s²)")
    axes[0].set_ylabel("position (m)")
    axes[1].set_ylabel("velocity (m/s)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(title)
    fig.tight_layout()
    save_figure(fig, path)


def _mm(x: float) -> str:
    return f"{x * 1e3:+.3f} mm"


class HintUse:
    """Whether the recording's standstill_hint column is used, and what it said (for the
    one line that tells the user)."""

    def __init__(self, args: argparse.Namespace):
        self.wanted = args.method in FILTER_METHODS
        self.ignore = args.ignore_hint
        self.present = False
        self.rest = self.moving = self.unknown = 0

    def of(self, series: AccelerationSeries):
        """The hint array to give the estimator for this series (chunk), or None."""
        hint = series.standstill_hint
        if hint is None or not self.wanted:
            return None
        self.present = True
        if self.ignore:
            return None
        self.rest += int(np.count_nonzero(hint == 1))
        self.moving += int(np.count_nonzero(hint == 0))
        self.unknown += int(np.count_nonzero(~np.isfinite(hint)))
        return hint

    def say(self) -> None:
        if not self.present:
            return
        if self.ignore:
            print("adxlgw estimate: the recording's standstill_hint column is ignored (--ignore-hint)",
                  file=sys.stderr)
        else:
            print(f"adxlgw estimate: using the recording's standstill_hint ({self.rest} samples 'at rest', "
                  f"{self.moving} 'moving', {self.unknown} unknown)", file=sys.stderr)


def _read_series(args: argparse.Namespace, source: RecordingSource) -> tuple[AccelerationSeries, str]:
    """The recording as acceleration (its form: raw or acceleration), checked: samples
    left after --skip-s, a time axis an estimate can run on."""
    per_sample = {"smoothed": SMOOTHED_BYTES_PER_SAMPLE, "zupt": ZUPT_BYTES_PER_SAMPLE,
                  "zupt-forward": ZUPT_BYTES_PER_SAMPLE}.get(args.method)
    if per_sample is not None:
        check_fits_in_memory(args.recording, per_sample * source.estimated_rows(),
                             f"the {args.method} estimate ({per_sample} bytes per sample)")
    # the host's arrival time and the temperature are not used here: not read
    wanted = [n for n in source.names if n not in ("t_host_s", "temp_c")] if not args.model else None
    with reading_bar(source) as bar:
        rec = read_all(source, columns=wanted, progress=bar)
    form = rec.form
    series = to_acceleration(rec)
    del rec  # the raw counts are not needed once converted (smoothed: ~40 bytes per sample)
    series = Skip(args.skip_s)(series)
    if args.skip_s and len(series) == 0:
        raise RecordingError(f"{args.recording}: no rows after the first {args.skip_s:g} s (--skip-s)")
    _warn_input(series)
    if len(series) < 2:
        raise RecordingError(f"{args.recording}: fewer than two samples, nothing to estimate")
    check_time_axis(args.recording, series.t_s)
    return series, form


def _estimated(args: argparse.Namespace, series: AccelerationSeries, form: str):
    """The track of the method asked for, and the filter's settings (None for raw/paper)."""
    drift = load_drift_model(args.drift_model) if args.drift_model else None
    settings = None
    try:
        if args.method in FILTER_METHODS:
            settings = with_travel(settings_for(series, form, args.noise_from, drift), args)
        hints = HintUse(args)
        hint = hints.of(series)

        def run_on(acc, settings=settings):
            return estimate_series(series.t_s, acc, series.valid, method=args.method, settings=settings,
                                   lost_before=series.lost_before if form == "raw" else None, standstill_hint=hint)

        if args.model:  # the extended model (gateway/commands/model_option.py)
            track, model_notes = estimate_with_model(args.model, series, settings, form, run_on)
            for note in model_notes:
                print(f"adxlgw estimate: {note}", file=sys.stderr)
        else:
            track = run_on(series.acc_mps2)
        hints.say()
    except NoRestError as err:
        raise _no_rest(args, err) from err
    return track, settings


def _report(args: argparse.Namespace, series: AccelerationSeries, track, settings) -> None:
    """The notes and settings, the track written, the errors against the reference, the plot."""
    for note in track.notes:
        print(f"adxlgw estimate: warning: {note}", file=sys.stderr)
    if settings is not None:
        for line in settings.describe():
            print(f"settings: {line}")
    write_track(args.out, track)
    print(f"wrote {args.out}: {len(track)} samples, method {track.method}")
    print_errors(args, *errors_of(series.t_s, track.pos_m, series.reference), float(track.pos_m[-1]))
    if args.plot:
        plot_track(args.plot, track, series.reference, f"{Path(args.recording).name}: {track.method}")
        print(f"wrote {args.plot}")


def run(args: argparse.Namespace) -> int:
    if args.plot:
        check_plot_path(args.plot)  # before the work
    source = open_recording(args.recording)
    if args.method == "realtime" and not args.plot and not args.model:
        return run_streamed(args, source)
    series, form = _read_series(args, source)
    track, settings = _estimated(args, series, form)
    _report(args, series, track, settings)
    return 0


def _warn_input(series: AccelerationSeries) -> None:
    for w in series.report.warnings():
        print(f"adxlgw estimate: warning: {w}", file=sys.stderr)


def errors_of(t_s, pos_m, ref) -> tuple[ErrorSummary | None, bool]:
    """(summary, with stops) against whatever reference the recording has (None: none)."""
    if "ref_pos_m" in ref and "ref_vel_mps" in ref:
        return summarise_errors(t_s, pos_m, ref["ref_pos_m"], ref["ref_vel_mps"], ref.get("ref_acc_mps2")), True
    if "ref_pos_m" in ref:
        err = pos_m - ref["ref_pos_m"]
        summary = ErrorSummary(stops=(), final_m=float(err[-1]), rms_m=math.sqrt(np.mean(err ** 2)), travelled_m=0.0)
        return summary, False
    return None, False


def print_errors(args, summary: ErrorSummary | None, with_stops: bool, final_pos_m: float) -> None:
    if summary is not None and with_stops:
        print(f"errors against the reference ({summary.travelled_m:.3f} m travelled):")
        for i, stop in enumerate(summary.stops, start=1):
            print(f"  stop {i:3d} at {stop.t_s:9.3f} s: {_mm(stop.error_m)}")
        print(f"  final: {_mm(summary.final_m)}   RMS: {summary.rms_m * 1e3:.3f} mm"
              + (f"   last stop: {summary.last_stop_percent_of_travel:.3g} % of distance travelled"
                 if summary.stops else ""))
    elif summary is not None:
        print(f"errors against the reference: final {_mm(summary.final_m)}   RMS {summary.rms_m * 1e3:.3f} mm")
    if args.returns_to_start:
        print(f"final position (the motion returns to its start, so this is the error): {_mm(final_pos_m)}")


class _Streamed:
    """The realtime estimate of one recording, fed chunk by chunk: the filter (its
    settings from the first chunk), the track's writer and the errors against the
    reference summed up as the chunks pass."""

    def __init__(self, args: argparse.Namespace, form: str) -> None:
        self._args = args
        self._form = form
        self._drift = load_drift_model(args.drift_model) if args.drift_model else None
        self.hints = HintUse(args)
        self.runner: RealtimeChunks | None = None
        self.writer = None
        self.settings = None
        self.judge: StreamedErrors | None = None
        self.ref_names: list[str] = []
        self.last_series: AccelerationSeries | None = None
        self.last_track = None

    def _start(self, series: AccelerationSeries) -> None:
        self.settings = with_travel(settings_for(series, self._form, self._args.noise_from, self._drift), self._args)
        self.runner = RealtimeChunks(self.settings)
        self.ref_names = [k for k, v in series.reference.items() if not np.all(np.isnan(v))]
        if "ref_pos_m" in self.ref_names:
            self.judge = StreamedErrors()

    def feed(self, series: AccelerationSeries) -> None:
        check_time_axis(self._args.recording, series.t_s)
        if self.runner is None:
            self._start(series)
        raw = self._form == "raw"
        track = self.runner.feed(series.t_s, series.acc_mps2, series.valid,
                                 series.lost_before if raw else None, self.hints.of(series))
        if self.writer is None:
            self.writer = track_writer(self._args.out, track)
        self.writer.write(track.columns())
        if self.judge is not None:
            ref, names = series.reference, self.ref_names
            self.judge.feed(track.t_s, track.pos_m, ref["ref_pos_m"],
                            ref["ref_vel_mps"] if "ref_vel_mps" in names else np.full(len(track), np.nan),
                            ref["ref_acc_mps2"] if "ref_acc_mps2" in names else None)
        self.last_series, self.last_track = series, track

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()


def run_streamed(args: argparse.Namespace, source: RecordingSource) -> int:
    """The realtime estimate chunk by chunk: memory follows the chunk, not the recording.

    The filter's settings come from the first chunk (for noise from the rest: its initial
    rest and its median period), and time gaps of the acceleration form are judged per
    chunk; a recording of one chunk (under 4 MiB of CSV, 2^17 Parquet rows) gives
    exactly the whole-file numbers. The errors against a reference are summed up as the
    chunks pass (StreamedErrors); a reference column empty in the first chunk is taken
    as absent (the whole-file path looks at the whole column)."""
    run = _Streamed(args, source.form)
    skip = Skip(args.skip_s)
    try:
        with reading_bar(source, "estimating") as bar:
            for series in acceleration_chunks(source, progress=bar):
                series = skip(series)
                if args.skip_s and not len(series):
                    continue
                run.feed(series)
        if run.runner is None:
            raise RecordingError(f"{args.recording}: no data rows"
                                 + (f" after the first {args.skip_s:g} s (--skip-s)" if args.skip_s else ""))
        notes = run.runner.finish()
        run.hints.say()
    except NoRestError as err:
        run.abort()
        raise _no_rest(args, err) from err
    except BaseException:
        run.abort()
        raise
    _warn_input(run.last_series)
    for note in notes:
        print(f"adxlgw estimate: warning: {note}", file=sys.stderr)
    for line in run.settings.describe():
        print(f"settings: {line}")
    run.writer.commit()
    print(f"wrote {args.out}: {run.runner.counts.samples} samples, method realtime")
    print_errors(args, run.judge.result() if run.judge is not None else None, "ref_vel_mps" in run.ref_names,
                 float(run.last_track.pos_m[-1]))
    return 0
