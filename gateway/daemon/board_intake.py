"""The daemon's board side without the wires: received chunks → the sample pipeline →
the events the status bits are made of, and the snapshot every wire shows.

No I/O and no event loop: the supervisor (gateway/daemon/supervisor.py) hands it chunks with their
arrival time (`receive`), and asks for the numbers when a wire needs them (`drain`,
`snapshot`). Kept apart from the supervisor so that its rules are tested on their own.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from drivers.published_values import PublishedValues, StatusExtBits, flag_word
from gateway.core import estimator_kernel as K
from gateway.core.estimator import HOLDING_FLAGS, Estimate
from gateway.daemon.sample_loop import OUTAGE_S
from gateway.daemon.sample_pipeline import ChunkResult, SamplePipeline
from gateway.daemon.status_flags import EVENT_HOLD_S, GatewayCondition, LinkHealth, status_bits

log = logging.getLogger("adxlgw")

# a clipped or an invalid sample shows on the wires at least this long
SATURATION_HOLD_S = 1.0
AXIS_INVALID_HOLD_S = 1.0
# A silence shorter than this on the host's clock is judged by the board's seq: a seq gap
# longer than sample_loop.OUTAGE_S of the board's clock starts the estimator over (the
# pipeline does it, at the gap), a backlog read late after a host stall lost nothing and
# keeps the estimate. A longer silence could hide a whole wrap of the 16-bit seq at the
# fastest period the data sheet allows (T2 ≥ 0.5 ms: 65536 × 0.5 ms), so the seq cannot
# prove that nothing was lost: start over.
SEQ_PROVES_CONTINUITY_S = 65536 * 0.5e-3
_SIMULATED = int(StatusExtBits.SIMULATED)
_HINT_AT_REST = int(StatusExtBits.HINT_AT_REST)
_HINT_MOVING = int(StatusExtBits.HINT_MOVING)
_HINT_CONFLICT = int(StatusExtBits.HINT_CONFLICT)
_OFFSET_STEP = int(StatusExtBits.OFFSET_STEP)
_STOP_BY_HINT = int(StatusExtBits.STOP_BY_HINT)
_MQTT_DOWN = int(StatusExtBits.MQTT_DOWN)


@dataclass(slots=True)
class BoardEvents:
    """When things last happened (monotonic s of the chunk that showed them)."""

    last_sample_s: float | None = None
    samples_lost_at_s: float | None = None
    board_reset_at_s: float | None = None
    estimator_fault_at_s: float | None = None
    saturated_until_s: float = -1.0
    axis_invalid_until_s: float = -1.0
    outage_at_s: float | None = None


class BoardIntake:
    """Chunks in (with their arrival time), estimates and published snapshots out."""

    def __init__(self, pipeline: SamplePipeline):
        self.pipeline = pipeline
        self.events = BoardEvents()
        self._inbox: list[tuple[float, bytes]] = []  # received, not yet through the pipeline
        self._heartbeat = 0
        self._published_at = -math.inf
        self._values = PublishedValues()
        self._values_built = True  # False: published since, build on the next read

    # ---------------------------------------------------------------- input --
    def receive(self, arrived_s: float, data: bytes) -> None:
        """Keep a chunk until `drain` (the supervisor decides when: see daemon.py)."""
        self._inbox.append((arrived_s, data))

    @property
    def waiting_since_s(self) -> float | None:
        """Arrival time of the oldest chunk not yet drained; None: nothing waits."""
        return self._inbox[0][0] if self._inbox else None

    @property
    def waiting_chunks(self) -> int:
        return len(self._inbox)

    def drain(self) -> bool:
        """Everything received so far through the pipeline, chunk by chunk; True if any
        sample was estimated. A sample's events carry its chunk's arrival time."""
        if not self._inbox:
            return False
        batch, self._inbox = self._inbox, []
        sampled = False
        for arrived_s, data in batch:
            last = self.events.last_sample_s
            if (last is not None and arrived_s - last > SEQ_PROVES_CONTINUITY_S
                    and self.pipeline.latest() is not None):
                log.warning("no samples for %.2f s, longer than the board's seq can account for: the axis "
                            "may have moved meanwhile; position not trusted until a stop is seen", arrived_s - last)
                self.pipeline.reset()
                self.events.outage_at_s = arrived_s
            sampled = self._take(arrived_s, self.pipeline.feed(data)) or sampled
        return sampled

    def _take(self, arrived_s: float, r: ChunkResult) -> bool:
        ev = self.events
        if r.board_reset:
            log.warning("board reset: continuity lost, position not referenced until the next tare")
            ev.board_reset_at_s = arrived_s
        if r.outage_s > 0.0:
            log.warning("%.2f s of samples lost on the line: the axis may have moved meanwhile; position "
                        "not trusted until a stop is seen", r.outage_s)
            ev.outage_at_s = arrived_s
        if r.estimator_fault:
            log.error("estimator state not finite or diverged: started over, position not referenced")
            ev.estimator_fault_at_s = arrived_s
        if not r.samples:
            return False
        ev.last_sample_s = arrived_s
        if r.samples_lost:
            ev.samples_lost_at_s = arrived_s
        if r.saturated:
            ev.saturated_until_s = arrived_s + SATURATION_HOLD_S
        if r.invalid:
            ev.axis_invalid_until_s = arrived_s + AXIS_INVALID_HOLD_S
        return True

    # --------------------------------------------------------------- output --
    def publish(self, now_s: float) -> None:
        """New values as of `now_s`: the heartbeat moves (the snapshot is built lazily)."""
        self._heartbeat = (self._heartbeat + 1) & 0xFFFFFFFF
        self._published_at = now_s
        self._values_built = False

    def snapshot(self, health: LinkHealth) -> PublishedValues:
        """What the wires show as of the last publish: built once per publish."""
        if not self._values_built:
            self._values = self._build(health)
            self._values_built = True
        return self._values

    def condition(self, now_s: float, health: LinkHealth) -> GatewayCondition:
        return self._condition(now_s, health, self.pipeline.latest())

    def status_ext(self, health: LinkHealth) -> StatusExtBits:
        return self._status_ext(health, self.pipeline.latest())

    # (_condition and _status_ext take the estimate read once per snapshot, and test its
    # flag bits directly: this runs for every snapshot, on a VM cold at each wakeup, and
    # a property or a call there costs more than the test it wraps)
    def _condition(self, now_s: float, health: LinkHealth, est: Estimate | None) -> GatewayCondition:
        ev = self.events
        flags = -1 if est is None else est.flags
        fault_at = ev.estimator_fault_at_s
        last_sample = ev.last_sample_s
        return GatewayCondition(
            now_s=now_s,
            have_estimate=est is not None,
            port_open=health.port_open,
            last_sample_s=last_sample,
            last_byte_s=health.last_byte_s,
            stale_after_s=health.stale_after_s,
            lost_after_s=health.lost_after_s,
            referenced=self.pipeline.referenced,
            standstill=est is not None and flags & K.F_STANDSTILL != 0,
            estimator_fault=(est is not None and flags & K.F_FAULT != 0)
            or (fault_at is not None and now_s - fault_at < EVENT_HOLD_S),
            holding=est is not None and (flags & HOLDING_FLAGS != 0 or flags & K.F_INITIALISED == 0),
            axis_invalid=now_s < ev.axis_invalid_until_s,
            saturated_until_s=ev.saturated_until_s,
            board_reset_at_s=ev.board_reset_at_s,
            samples_lost_at_s=ev.samples_lost_at_s,
            config_reloaded_at_s=health.config_reloaded_at_s,
            bias_estimating=est is not None and flags & K.F_BIAS_ESTIMATING != 0,
            # silent longer than an outage: whatever comes next, the axis may have moved; and
            # before the first estimate of a (re)start with the velocity unknown, the position
            # shown (the last saved one) is not trustworthy either
            untrusted=(flags & K.F_UNTRUSTED != 0 if est is not None else self.pipeline.estimator.position_untrusted)
            or (last_sample is not None and now_s - last_sample > OUTAGE_S),
        )

    def _status_ext(self, health: LinkHealth, est: Estimate | None) -> StatusExtBits:
        bits = _SIMULATED if health.simulated else 0
        if health.mqtt_down:
            bits |= _MQTT_DOWN
        hint = self.pipeline.hint
        if hint is not None:
            bits |= _HINT_AT_REST if hint else _HINT_MOVING
        if est is not None:
            flags = est.flags
            if flags & K.F_HINT_CONFLICT:
                bits |= _HINT_CONFLICT
            if flags & K.F_OFFSET_STEP:
                bits |= _OFFSET_STEP
            if flags & K.F_STANDSTILL and self.pipeline.stop_by_hint:
                bits |= _STOP_BY_HINT
        return flag_word(StatusExtBits, bits)

    def _build(self, health: LinkHealth) -> PublishedValues:
        now = self._published_at
        est: Estimate | None = self.pipeline.latest()
        if est is not None:
            pos, vel, acc, bias, pos_std = est.pos_m, est.vel_mps, est.acc_mps2, est.bias_mps2, est.pos_std_m
        else:  # nothing estimated since start or a start-over: the last numbers, flagged
            last = self._values
            pos, vel, acc = last.position_m, last.velocity_mps, last.acceleration_mps2
            bias, pos_std = last.bias_estimate_mps2, last.position_std_m
        p = self.pipeline
        c = p.decoder_counters
        last_sample = self.events.last_sample_s
        return PublishedValues(
            position_m=pos, velocity_mps=vel, acceleration_mps2=acc,
            status=status_bits(self._condition(now, health, est)),
            heartbeat=self._heartbeat,
            sample_counter=p.counters.samples,
            last_sample_age_ms=None if last_sample is None else (now - last_sample) * 1000,
            bias_estimate_mps2=bias, position_std_m=pos_std,
            board_temp_c=p.board.temp_c,
            lost_samples=c.samples_lost, crc_errors=c.crc_errors,
            board_resets=p.counters.resets_announced + p.counters.resets_inferred,
            can_send_errors=health.can_send_errors,
            can_refused_commands=health.can_refused_commands,
            mqtt_dropped=health.mqtt_dropped,
            status_ext=self._status_ext(health, est),
        )
