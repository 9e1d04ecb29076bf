"""The built-in virtual board: a simulated run streamed as the board's serial bytes.

HELLO first, SAMPLE frames paced by the board's own clock (each sent when its sensor
period ends), STATUS once a second. Optional faults for tests and demos: garbage
bytes, bursts, single samples lost, the line cut for a while, board resets, and the
port vanishing and coming back.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from drivers.board_protocol import encode_hello, encode_sample_records, encode_status
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import SimulatedRun, simulate
from gateway.core.units import SEQ_MODULUS

log = logging.getLogger(__name__)

FW_VERSION = (1, 0)


@dataclass(frozen=True)
class FaultSettings:
    """Each period (and the cut's start and length) in seconds of board time; 0 disables
    the fault."""

    garbage_every_s: float = 0.0  # random bytes between frames
    burst_every_s: float = 0.0  # hold frames back for 50 ms, then send them at once
    reset_every_s: float = 0.0  # the board restarts: HELLO, seq from 0
    reopen_every_s: float = 0.0  # the port vanishes for reopen_gap_s, then a new one appears
    reopen_gap_s: float = 0.5
    drop_every_s: float = 0.0  # a sample lost on the line (never sent)
    # Once, cut_after_s into the board's run (0: never), the line is cut for cut_for_s:
    # nothing the board writes meanwhile arrives, while its seq and clock run on (a UART
    # wire pulled and put back, unlike a board that stalls and then writes what it owes).
    cut_after_s: float = 0.0
    cut_for_s: float = 1.0


@dataclass(frozen=True)
class EmulatorSettings:
    scenario: ScenarioSettings = ScenarioSettings()
    sensor: SensorParams = SensorParams()
    seed: int = 0
    loop: bool = False  # repeat the scenario forever (seq and time continue)
    faults: FaultSettings = FaultSettings()


@dataclass
class Chunk:
    """Bytes due at one board time (s since the board's reset)."""

    due_s: float
    data: bytes
    kind: str  # "hello", "sample", "status", "garbage"
    samples: int = 0


def _runs(settings: EmulatorSettings) -> Iterator[SimulatedRun]:
    profile = build_profile(settings.scenario)
    block = 0
    while True:
        yield simulate(profile, settings.sensor, seed=settings.seed + block)
        block += 1
        if not settings.loop:
            return


def board_schedule(settings: EmulatorSettings) -> Iterator[Chunk]:
    """What reaches the line's far end, as timed chunks, in order; infinite with loop=True."""
    return _cut_line(_board_output(settings), settings.faults)


def in_line_cut(due_s: float, faults: FaultSettings) -> bool:
    """True for board times inside the line's cut: [cut_after_s, cut_after_s + cut_for_s)."""
    start = faults.cut_after_s
    return start > 0.0 and start <= due_s < start + faults.cut_for_s


def _cut_line(chunks: Iterator[Chunk], faults: FaultSettings) -> Iterator[Chunk]:
    """The chunks less those written while the line was cut: the board does not know,
    so its seq, clock and STATUS reports run on as if they had arrived."""
    cut = False
    for chunk in chunks:
        now_cut = in_line_cut(chunk.due_s, faults)
        if now_cut != cut:
            cut = now_cut
            log.info("line %s at board time %.3f s", "cut" if cut else "back", chunk.due_s)
        if not cut:
            yield chunk


def _board_output(settings: EmulatorSettings) -> Iterator[Chunk]:
    """The board's output as timed chunks, in order, as it writes them."""
    faults = settings.faults
    rng = np.random.default_rng([settings.seed, 0xE3])
    tick_hz = int(round(settings.sensor.tick_hz))
    temp_centi = int(round(settings.sensor.temperature_c * 100))
    report = dict(tick_hz=tick_hz, temp_centi_c=temp_centi, fw_major=FW_VERSION[0], fw_minor=FW_VERSION[1])
    yield Chunk(0.0, encode_hello(uptime_s=0, **report), "hello")
    t_offset = 0.0
    seq_offset = 0
    next_status_s = 1.0
    next_garbage = faults.garbage_every_s or np.inf
    next_reset = faults.reset_every_s or np.inf
    next_drop = faults.drop_every_s or np.inf
    reset_base_s = 0.0  # board time of the last reset (uptime counts from it)
    last_seq = SEQ_MODULUS - 1
    for run in _runs(settings):
        records = encode_sample_records(
            (run.seq + seq_offset) % SEQ_MODULUS, run.t1x, run.t1y, run.t2, run.flags
        )
        ends = t_offset + run.t_s + run.t2 / run.tick_hz  # a sample leaves when its period ends
        for k in range(len(run)):
            due = float(ends[k])
            while next_status_s <= due:
                uptime = int(next_status_s - reset_base_s)
                yield Chunk(next_status_s, encode_status(seq=last_seq, uptime_s=uptime, **report), "status")
                next_status_s += 1.0
            if due >= next_garbage:
                yield Chunk(due, rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes(), "garbage")
                next_garbage += faults.garbage_every_s
            if due >= next_reset:
                # the board restarts: HELLO, then seq starts again at 0
                reset_base_s = due
                seq_offset = (seq_offset - int(records["seq"][k])) % SEQ_MODULUS
                records = encode_sample_records(
                    (run.seq + seq_offset) % SEQ_MODULUS, run.t1x, run.t1y, run.t2, run.flags
                )
                yield Chunk(due, encode_hello(uptime_s=0, **report), "hello")
                next_reset += faults.reset_every_s
            if due >= next_drop:
                next_drop += faults.drop_every_s
                last_seq = int(records["seq"][k])
                continue
            last_seq = int(records["seq"][k])
            yield Chunk(due, records[k].tobytes(), "sample", samples=1)
        t_offset = float(ends[-1])
        seq_offset = (seq_offset + len(run)) % SEQ_MODULUS


class Pacer:
    """Sleeps until each chunk's due time (real time), or not at all (fast)."""

    def __init__(self, fast: bool, clock: Callable[[], float] = time.monotonic, sleep=time.sleep):
        self.fast = fast
        self.clock = clock
        self.sleep = sleep
        self.start = clock()

    def wait_until(self, due_s: float) -> None:
        if self.fast:
            return
        delay = self.start + due_s - self.clock()
        if delay > 0:
            self.sleep(delay)
