"""What an estimator without the machine's word can know at the end of each robot move,
sample by sample (causally): whether the detector can see the stop before the move is
scored, and how well the past tells the offset the move is integrated with.

    nice .venv/bin/python -m benchmarks.accuracy.causal_bound [--json PATH]

Per move of each robot file (sensor clock, imported as the corpus benchmark imports it;
moves between the robot's rests as `gateway.core.evaluation.move_errors` takes them, each
scored at the last sample of the rest that ends it):

- `end rest`: how long the robot stands before the move is scored, in seconds and in
  detector windows (`standstill_window_s`); the machine's "at rest" may lead the sensor's
  stop by tens of ms;
- `quiet samples in it`: samples of that end rest covered by a window of the detector
  lying wholly inside it that the quiet test passes (`zupt_smoother.quiet_samples` on the
  end rest alone, against its own level: as generous to a detector as it can be) — 0: no
  stop can be seen before the move is scored, and a causal estimate there is dead
  reckoning from the rest before;
- `level wander`: how much the axis's reading at rest moves from one half-second to the
  next in the rest before the move (the standard deviation of its 0.5 s medians, the
  white noise's share removed; — when that rest holds fewer than three) — the offset a
  move is integrated with is known no better than that from the past;
- `its position σ`: ½·wander·T² over the move's duration T, % of the move — the position
  uncertainty that offset alone leaves at the move's end when no stop inside it is seen.

Where the end rest holds no quiet window and that σ is several % of the move, no causal
estimate without the machine's word can promise a few % on the move.

With the machine's word (the realtime estimate given the robot's `standstill_hint`, as
`adxlgw estimate` runs): the stop the hint opens at the end of the move finds the velocity
the offset left (`hinted stop: v found`; — when the end rest holds no stop), and its ZUPT
moves the position by Cov(p, v)/Var(v) times it (`its correction`) — right if that
velocity error grew as the filter's model says (a random walk: y·T/2), off by up to all
of it either way if it arose at the move's start or end (an offset that grows with the
travel leaves y·T/3: a third of it too much). `error after`: the
estimate's error at the scored sample, % of the move.
"""
from __future__ import annotations

import numpy as np

from benchmarks import harness
from benchmarks.accuracy.estimation_corpus import ROBOT_FILES, robot_case
from gateway.core.evaluation import move_errors
from gateway.core.runs import true_runs

BLOCK_S = 0.5  # the level's blocks: long against the noise (√n), short against a move


def quiet_samples_in(case, first: int, last: int) -> int:
    """Samples first … last that a quiet window lying wholly inside them covers, by the
    quiet test of the offline ZUPT smoother (`zupt_smoother.quiet_samples` on that stretch
    alone, its rest level the stretch's own): the stops a detector can see there."""
    from gateway.core.zupt_smoother import quiet_samples

    span = slice(first, last + 1)
    return int(quiet_samples(case.t_s[span], case.acc_mps2[span], np.asarray(case.valid, dtype=bool)[span],
                             case.settings).sum())


def level_wander(t, acc, ok, first: int, last: int, noise_std: float) -> float:
    """The standard deviation of the rest's BLOCK_S medians, the white noise's share
    (median of n: ≈ 1.25·σ/√n) removed; NaN with fewer than 3 blocks."""
    edges = np.arange(t[first], t[last], BLOCK_S)[:-1]
    meds, counts = [], []
    for e in edges:
        sel = (t >= e) & (t < e + BLOCK_S) & ok
        sel[:first] = False
        sel[last + 1:] = False
        if sel.sum() >= 3:
            meds.append(np.median(acc[sel]))
            counts.append(sel.sum())
    if len(meds) < 3:
        return float("nan")
    noise_var = (1.2533 * noise_std) ** 2 / float(np.mean(counts))
    return float(np.sqrt(max(np.var(meds, ddof=1) - noise_var, 0.0)))


def hinted_track(case):
    """The realtime estimate given the robot's standstill hint, as `adxlgw estimate` runs."""
    from gateway.core.estimator import estimate_series

    return estimate_series(case.t_s, case.acc_mps2, case.valid, method="realtime", settings=case.settings,
                           standstill_hint=case.rest.astype(float))


def hinted_stop(track, first: int, last: int) -> tuple[float, float]:
    """(the velocity the first stop inside samples first … last found, the position its
    ZUPT moved); NaN when no stop was entered there."""
    from gateway.core.estimator_kernel import F_ENTRY

    entries = np.flatnonzero(track.flags[first:last + 1] & F_ENTRY) + first
    if not entries.size:
        return float("nan"), float("nan")
    i = int(entries[0])
    return float(track.zupt_velocity_error_mps[i]), float(track.pos_m[i] - track.pos_m[i - 1])


def move_rows(case) -> list[dict]:
    """One row per move of the case (see the module's doc)."""
    t, acc, ok = case.t_s, case.acc_mps2, np.asarray(case.valid, dtype=bool)
    s = case.settings
    first_of_rest = {stop - 1: start for start, stop in true_runs(case.rest)}  # last sample → first
    hinted = hinted_track(case)
    rows = []
    for move in move_errors(np.zeros(t.size), case.ref_m, case.rest):
        a, b = move.start, move.end  # last samples of the rest before and of the rest after
        wander = level_wander(t, acc, ok, first_of_rest[a], a, s.sample_noise_std_mps2)
        duration_s = float(t[first_of_rest[b]] - t[a])
        end_rest_s = float(t[b] - t[first_of_rest[b]])
        v_found, correction = hinted_stop(hinted, first_of_rest[b], b)
        hinted_error = (hinted.pos_m[b] - hinted.pos_m[a]) - move.ref_m
        rows.append({"hinted_stop_v_mps": v_found, "hinted_correction_m": correction,
                     "hinted_error_pct": 100.0 * float(hinted_error) / abs(move.ref_m),
                     "move_m": move.ref_m, "duration_s": duration_s, "end_rest_s": end_rest_s,
                     "end_rest_windows": end_rest_s / s.standstill_window_s,
                     "quiet_samples_in_end_rest": quiet_samples_in(case, first_of_rest[b], b),
                     "level_wander_mps2": wander,
                     "offset_position_std_pct": 100.0 * 0.5 * wander * duration_s ** 2 / abs(move.ref_m)})
    return rows


def main() -> int:
    parser = harness.parser(__doc__)
    args = parser.parse_args()
    run = harness.stamp(__spec__.name)
    print()
    print("| file | move | duration | end rest | quiet samples in it | level wander | its position σ "
          "| hinted stop: v found | its correction | error after |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    results = {}
    for name in ROBOT_FILES:
        case = robot_case(name, "sensor")
        if case.error:
            print(f"| {name} | {case.error} | | | | | | | | |")
            continue
        results[name] = rows = move_rows(case)
        for r in rows:
            wander, sigma = ("—", "—") if np.isnan(r["level_wander_mps2"]) else (
                f"{r['level_wander_mps2'] * 1e3:.0f} mm/s²", f"{r['offset_position_std_pct']:.1f} %")
            stop = "— | —" if np.isnan(r["hinted_stop_v_mps"]) else (
                f"{r['hinted_stop_v_mps']:+.3f} m/s | {r['hinted_correction_m'] * 1e3:+.0f} mm")
            print(f"| {name.removesuffix('.csv')} | {r['move_m']:+.3f} m | {r['duration_s']:.2f} s | "
                  f"{r['end_rest_s']:.2f} s ({r['end_rest_windows']:.1f} windows) | "
                  f"{r['quiet_samples_in_end_rest']} | {wander} | {sigma} | {stop} | "
                  f"{r['hinted_error_pct']:+.1f} % |")
    harness.write_json(args, results, run)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
