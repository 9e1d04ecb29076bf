"""Every sample of the fault cases through the daemon's own intake: what any read could show.

    .venv/bin/python -m benchmarks.daemon.fault_replay [--cases NAME,...] [--seeds 3]

benchmarks/daemon/fault_benchmark.py scores the reads a poller happened to make (one every
20 ms: one sample in ten) of a daemon on a pty; on a loaded machine which samples those are
changes from run to run. Here each case's board script (testing/fault_cases.py, the same
bytes) goes through the daemon's BoardIntake and SamplePipeline — the code between the
serial port and the wires — one frame at a time, arriving at its slot time, and the
snapshot a Modbus read would get is built after every sample. A sample counted here is a
read some load could have landed on: the goal (issue 31) is none VALID with
|error| > 3·POSITION_STD. No process, no timing: the same numbers on any machine.

Not replayed: the cases that kill and restart the daemon or start it on a forged state
file (they need the process and its state file: fault_benchmark plays them).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from benchmarks.harness import parser, stamp, write_json
from drivers.board_protocol import encode_hello
from drivers.published_values import StatusBits
from gateway.config import load_config
from gateway.daemon.board_intake import BoardIntake
from gateway.daemon.sample_pipeline import SamplePipeline
from gateway.daemon.settings import calibration_from, estimator_settings_from
from gateway.daemon.status_flags import LinkHealth
from testing.fault_cases import HELLO_REPORT, SLOT_S, Case, all_cases, board_script

NEEDS_THE_PROCESS = ("restart", "moved", "hostile")


@dataclass
class Replayed:
    samples: int = 0
    valid: int = 0
    valid_beyond_3sigma: list[tuple[int, float, float]] | None = None  # (slot, error m, σ m)


def replay(case: Case, seed: int) -> Replayed:
    """The case's frames one by one through the shipped config's intake; every snapshot scored."""
    cfg = load_config(None)
    script = board_script(case, seed)
    pipeline = SamplePipeline(calibration_from(cfg), estimator_settings_from(cfg), cfg.calibration.axis,
                              start_at_rest=True, travel_m=tuple(cfg.estimator.travel_m))
    intake = BoardIntake(pipeline)
    health = LinkHealth(port_open=True, last_byte_s=0.0, stale_after_s=cfg.serial.stale_after_ms / 1000,
                        lost_after_s=cfg.serial.lost_after_ms / 1000)
    intake.receive(0.0, encode_hello(uptime_s=0, **HELLO_REPORT))
    intake.drain()
    out = Replayed(valid_beyond_3sigma=[])
    for slot, frame in enumerate(script.frames):
        if not frame:
            continue
        arrived_s = 1.0 + slot * SLOT_S
        intake.receive(arrived_s, frame)
        if not intake.drain():
            continue
        intake.publish(arrived_s)
        values = intake.snapshot(replace(health, last_byte_s=arrived_s))
        out.samples += 1
        if not values.status & StatusBits.VALID:
            continue
        out.valid += 1
        error_m = values.position_m - script.ref_pos_m[slot]
        if not abs(error_m) <= 3 * values.position_std_m:
            out.valid_beyond_3sigma.append((slot, float(error_m), float(values.position_std_m)))
    return out


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--cases", default="", help="comma-separated substrings of case names (default: all replayable)")
    ap.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 of the simulated noise (default: 3)")
    args = ap.parse_args()
    run = stamp("benchmarks.daemon.fault_replay")
    wanted = [w.strip() for w in args.cases.split(",") if w.strip()]
    cases = [c for c in all_cases() if c.kind not in NEEDS_THE_PROCESS
             and (not wanted or any(w in c.name for w in wanted))]
    if not cases:
        raise SystemExit(f"--cases: no replayable case matches {args.cases!r}")
    print("| case | seed | samples | VALID | VALID with \\|error\\| > 3σ | first of them: slot, error, σ (µm) |")
    print("| --- | --- | --- | --- | --- | --- |")
    results = []
    for case in cases:
        for seed in range(args.seeds):
            r = replay(case, seed)
            bad = r.valid_beyond_3sigma
            first = "–" if not bad else f"{bad[0][0]}, {bad[0][1] * 1e6:+.2f}, {bad[0][2] * 1e6:.3f}"
            print(f"| {case.name} | {seed} | {r.samples} | {r.valid} | {len(bad)} | {first} |", flush=True)
            results.append({"case": case.name, "seed": seed, "samples": r.samples, "valid": r.valid,
                            "valid_beyond_3sigma": [list(b) for b in bad]})
    total = sum(len(r["valid_beyond_3sigma"]) for r in results)
    print(f"samples VALID beyond 3σ over all cases and seeds: {total} (goal 0)")
    write_json(args, results, run)


if __name__ == "__main__":
    main()
