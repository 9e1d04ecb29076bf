"""The fault benchmark's cases (benchmarks/daemon/fault_benchmark.py) as board scripts: the
paper's strokes with one fault each — a gap, an outage, a restart, a board reset, an offset
step, an axis moved while the daemon was down, a hostile state file — the bytes a writer
plays in 2 ms slots and the truth, so that tests can check a script carries the fault it
claims without running the daemon."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from drivers.board_protocol import encode_hello, encode_sample_records
from gateway.core.motion_profiles import PiecewiseConstantAcceleration, Segment, StrokeSettings, reciprocating_strokes
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import ErrorTerm, simulate

#: the board's default output, SAMPLE frames per second (the writer's slot is 1/RATE_HZ)
RATE_HZ = 500.0
SLOT_S = 1.0 / RATE_HZ
STROKE = StrokeSettings()  # the paper's: 0.1 s acceleration, 0.2 s cruise, 0.1 s deceleration, 1 s dwell
#: for the restarts: a robot-like move (0.8 m at 0.25 m/s, 3.1 s of cruise) — the daemon
#: takes 0.3–2 s to come back here, so on the paper's 0.2 s cruise it would come back at rest
LONG_STROKE = StrokeSettings(stroke_m=0.8, max_speed_mps=0.25, max_acc_mps2=2.5)
#: where in a stroke each phase's fault is centred, s after the stroke starts (paper stroke)
PHASE_S = {"acceleration": 0.05, "cruise": 0.20, "deceleration": 0.35, "rest": 0.90}
LONG_CRUISE_AT_S = 1.1  # the restart: 1 s into the long stroke's cruise, 2.1 s of it left
FAULT_STROKE = 2  # the third stroke: two strokes and stops seen before the fault
STOPS_SCORED = 3
HELLO_REPORT = dict(tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)


@dataclass(frozen=True)
class Case:
    name: str
    kind: str  # none, gap, outage, restart, reset, offset, moved (while down), hostile (state file)
    phase: str = "cruise"
    length_s: float = 0.0  # gap or outage
    restart_at_rest: bool = False  # restart: start_at_rest on the second start
    rest_s: float = STROKE.dwell_s  # the first true stop after the fault lasts this long


#: the machine's travel as its integrator configures it (estimator.travel_m): the long
#: stroke's 0–0.8 m with 0.2 m to spare. A cruise at the estimator's speed floor (0.1 m/s)
#: lasts at most 12 s within it (EstimatorSettings.quiet_stop_s)
TRAVEL_M = (-0.2, LONG_STROKE.stroke_m + 0.2)
#: the rests after a fault: the paper's 1 s dwell, a PLC's pause, and one longer than any
#: cruise within the travel, where a stop is accepted on quiet alone
RESTS_S = (1.0, 5.0, 20.0)
#: the hostile state file: a number within the state file's own limits, the orderly-stop mark
HOSTILE_POSITION_M = 9999.0


def all_cases() -> list[Case]:
    cases = [Case("no fault", "none")]
    for gap_ms in (5, 10, 20, 50):
        for phase in PHASE_S:
            cases.append(Case(f"gap {gap_ms} ms, {phase}", "gap", phase, gap_ms / 1000))
    for rest_s in RESTS_S:
        r = f", rest {rest_s:g} s"
        cases += [
            Case("restart (kill -9), start_at_rest=false on restart" + r, "restart", rest_s=rest_s),
            Case("restart (kill -9), same config (start_at_rest=true)" + r, "restart", restart_at_rest=True,
                 rest_s=rest_s),
            Case("board reset (HELLO, seq from 0)" + r, "reset", rest_s=rest_s),
            Case("outage 2 s" + r, "outage", length_s=2.0, rest_s=rest_s),
            Case("outage 8 s" + r, "outage", length_s=8.0, rest_s=rest_s),
        ]
    cases += [
        Case("offset step 5 mg", "offset"),
        # an orderly stop (SIGTERM) at rest at +0.3 m, the axis moved back to 0 while the
        # gateway was down, a start again with start_at_rest = true
        Case("orderly stop at rest, axis moved while down (start_at_rest=true)", "moved", restart_at_rest=True,
             length_s=3.0),
        # a state file within its own limits, with the orderly-stop mark: 9999 m
        Case(f"state file says {HOSTILE_POSITION_M:g} m, stopped at rest (start_at_rest=true)", "hostile"),
    ]
    return cases


@dataclass
class OffsetStep(ErrorTerm):
    """The sensor's offset steps by step_g at at_s and stays (a knock on the mount)."""

    at_s: float
    step_g: float
    name = "offset_step"

    def acceleration_g(self, ctx, ax, ay):
        return ax + np.where(ctx.t_s >= self.at_s, self.step_g, 0.0), ay


@dataclass
class BoardScript:
    """What the writer plays (bytes per 2 ms slot; empty: the line is silent) and the truth."""

    frames: list[bytes]
    ref_pos_m: np.ndarray
    fault_slot: int  # first slot the fault touches
    fault_end_slot: int  # first slot after it (== fault_slot for an instant fault)
    stops: list[tuple[int, int]]  # true rests: first and last slot
    kill_slot: int | None = None  # restart: when the daemon is killed (moved: stopped in order)
    restart_slot: int | None = None  # moved: when it is started again (else: at once)


def with_rest_after(profile: PiecewiseConstantAcceleration, after_s: float, rest_s: float,
                    ) -> PiecewiseConstantAcceleration:
    """The profile with its first rest that begins after `after_s` lasting `rest_s`."""
    segments = list(profile.segments)
    t = v = 0.0
    for k, seg in enumerate(segments):
        if seg.acc_mps2 == 0.0 and abs(v) < 1e-12 and t > after_s:
            segments[k] = Segment(rest_s, 0.0)
            break
        t += seg.duration_s
        v += seg.acc_mps2 * seg.duration_s
    return PiecewiseConstantAcceleration(segments)


def rest_intervals(ref_vel_mps: np.ndarray, min_slots: int) -> list[tuple[int, int]]:
    still = np.concatenate([[False], ref_vel_mps == 0.0, [False]])
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=False) if b - a >= min_slots]


def board_script(case: Case, seed: int = 0) -> BoardScript:
    # long enough for the fault, the daemon's way back and STOPS_SCORED stops after it
    stroke = LONG_STROKE if case.kind == "restart" else STROKE
    busy_s = case.length_s + (2.0 if case.kind in ("restart", "moved") else 0.5)
    move_s = 2 * stroke.max_speed_mps / stroke.max_acc_mps2 + (
        stroke.stroke_m - stroke.max_speed_mps ** 2 / stroke.max_acc_mps2) / stroke.max_speed_mps
    period_s = move_s + stroke.dwell_s
    strokes = FAULT_STROKE + 1 + math.ceil(busy_s / period_s) + STOPS_SCORED
    settings = replace(stroke, strokes=strokes)
    stroke_start_s = settings.rest_start_s + FAULT_STROKE * period_s
    if case.kind == "moved":
        # stopped in order in the dwell after the fault stroke (at +0.3 m), the axis back at
        # 0 while the gateway is down (the dwell lasts the downtime), started again there
        fault_s = stroke_start_s + move_s + 0.5 * stroke.dwell_s
        profile = with_rest_after(reciprocating_strokes(settings), fault_s, stroke.dwell_s + case.length_s)
    elif case.kind == "hostile":
        fault_s = 0.0
        profile = build_profile(ScenarioSettings(strokes=settings))
    else:
        centre_s = stroke_start_s + (LONG_CRUISE_AT_S if case.kind == "restart" else PHASE_S[case.phase])
        fault_s = centre_s - case.length_s / 2 if case.kind == "gap" else centre_s
        recovered_s = fault_s + case.length_s + (1.0 if case.kind == "restart" else 0.0)
        profile = with_rest_after(build_profile(ScenarioSettings(strokes=settings)), recovered_s, case.rest_s)
    terms = (OffsetStep(fault_s, 5e-3),) if case.kind == "offset" else ()
    run = simulate(profile, seed=seed, error_terms=terms)
    # the board's own period (its t2 counts) is not exactly the writer's 2 ms slot: the
    # fault's slot is found on the simulated sample times, its length in board periods
    fault_slot = int(np.searchsorted(run.t_s, fault_s))
    end_slot = fault_slot + int(round(case.length_s / (run.t_s[1] - run.t_s[0])))
    restart_slot = None
    if case.kind == "moved":  # back in the gateway's hands once the axis rests at its new place
        first_rest = next(a for a, _ in rest_intervals(run.ref_vel_mps, 1) if a > fault_slot)
        restart_slot = first_rest + int(0.5 / SLOT_S)
        end_slot = restart_slot
    seq = run.seq.astype(np.int64)
    if case.kind == "reset":
        seq[fault_slot:] -= seq[fault_slot]  # the board counts from 0 again after its HELLO
    records = encode_sample_records(seq % 65536, run.t1x, run.t1y, run.t2, run.flags)
    frames = [records[k].tobytes() for k in range(len(run))]
    if case.kind in ("gap", "outage"):
        for k in range(fault_slot, end_slot):
            frames[k] = b""
    if case.kind == "reset":
        frames[fault_slot] = encode_hello(uptime_s=0, **HELLO_REPORT) + frames[fault_slot]
    return BoardScript(frames, run.ref_pos_m, fault_slot, end_slot,
                       rest_intervals(run.ref_vel_mps, int(0.5 / SLOT_S)),
                       kill_slot=fault_slot if case.kind in ("restart", "moved") else None,
                       restart_slot=restart_slot)
