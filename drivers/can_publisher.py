"""Cyclic CAN publisher of `PublishedValues`, and receiver of the command frame.

The cyclic frames are sent from our own asyncio loop on a monotonic schedule rather
than python-can's periodic tasks, because every transmission needs a new alive counter
and CRC. The schedule is drift-free (due += period); when the loop was blocked for
more than a period it resynchronises instead of sending a burst, and counts the lapse.
One transmission of the frame pair per due time, whichever way it is triggered, so the
alive counter advances by exactly one per frame and a receiver's profile 1 check holds.

How a due time turns into a transmission (`CanPublisherConfig`):

- `sync_to_updates` (the default): at the first `update()` from a quarter period
  before the due time on, inside that call, so the frames carry the values the moment
  they arrive; if none comes within half a period after the due time, a timer sends
  the values it has. The next due time is one period on, or three quarters of a period
  after this transmission if that is later. So with updates more often than the period
  (the daemon woken per board sample) it is one frame pair per period, gaps within
  8–12 ms at 2 ms updates and 10 ms periods; with updates once per period (the daemon
  woken per batch of samples, see serial.batch_frames) the cycle locks onto them
  whatever their phase, each update sends, and the timer never fires — where a due
  time exactly at the update would have sent every other cycle from the timer. Gaps
  are 0.5–1.75 periods, on average one period.
- otherwise on the timer alone, exactly at the due time (strictly cyclic).
- `min_interval_ms` (either way): `update()` also sends at once when at least that long
  has passed since the last transmission, and the cycle restarts from that
  transmission (AUTOSAR COM's "mixed" transmission mode: more frames than one per
  period, e.g. one per sample with 0).

The timer is a loop callback that is re-armed on every transmission, so while updates
trigger the frames it never wakes the process.

A failed send (can.CanError: buffer full, bus off, interface down) is counted and
logged at a limited rate; the loop keeps going. Commands arrive through a python-can
Notifier; only frames that pass the E2E check are acted upon, and only when commands
are enabled. Every command frame is answered with an ADXL_CommandAck.

Replays: a command's counter must be 1..MAX_COUNTER_DELTA ahead of the last accepted
one's, so an older frame played again (or the same one) is refused as COUNTER_ERROR and
counted (commands_rejected, Modbus CAN_REFUSED_COMMANDS). A sender that restarted (its
counter anywhere) is back in step after two frames with consecutive counters within
COMMAND_RESYNC_S: the first is refused, the second carried out. A limit: the counter is 4
bits without a key, so a recorded pair of consecutive frames played again within the
window, or a first frame after the gateway starts, cannot be told from the sender's own
(what the bus's access control is for). Refused frames are logged as one line per reason
and `refused_log_interval_s`, with a count (drivers/peer_log.py).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import can

from .can_frames import (
    DEFAULT_FRAMES,
    AckResult,
    CommandCheck,
    CyclicEncoder,
    FrameTable,
    check_command,
    encode_ack,
    next_counter,
)
from .peer_log import PeerLogLimiter
from .published_values import NOTHING_PUBLISHED, CommandCallback, ValuesSource, current

log = logging.getLogger(__name__)


class CanPublisherError(Exception):
    """The CAN bus could not be opened (unknown interface, missing channel, …).

    Local to this module until the lead reconciles it with drivers/errors.py.
    """


@dataclass(frozen=True, slots=True)
class CanPublisherConfig:
    """Settings; the names match the [can] section of the daemon's config."""

    #: python-can interface name: "socketcan" in production, "virtual" in tests.
    interface: str = "socketcan"
    channel: str = "can0"
    #: Passed to can.Bus when set (interfaces that configure the bit rate themselves;
    #: socketcan takes it from `ip link`).
    bitrate: int | None = None
    period_ms: float = 10.0
    #: Each cycle's frames go out at the first update() from a quarter period before
    #: their due time (a timer sends them half a period after it if none comes);
    #: False: exactly on the timer.
    sync_to_updates: bool = True
    #: None: one transmission per period. A number: update() also transmits at once
    #: when at least this long has passed since the last transmission.
    min_interval_ms: float | None = None
    #: Commands over CAN are refused (acknowledged as DISABLED) unless enabled.
    commands_enabled: bool = False
    #: The frames' identifiers (can_frames.frame_table(base_id)): several gateways on one bus.
    frames: FrameTable = DEFAULT_FRAMES
    #: Further keyword arguments for can.Bus (bitrate, fd, …).
    bus_options: Mapping[str, Any] = field(default_factory=dict)
    #: At most one log line per this interval about failing sends.
    send_error_log_interval_s: float = 10.0
    #: Refused command frames: one log line per reason and this interval, with a count.
    refused_log_interval_s: float = 10.0

    def __post_init__(self) -> None:
        if not self.period_ms > 0:
            raise CanPublisherError(f"period_ms must be > 0, got {self.period_ms}")
        if self.min_interval_ms is not None and not 0 <= self.min_interval_ms <= self.period_ms:
            raise CanPublisherError(
                f"min_interval_ms must be within 0..period_ms, got {self.min_interval_ms}"
            )
        object.__setattr__(self, "bus_options", MappingProxyType(dict(self.bus_options)))


@dataclass(frozen=True, slots=True)
class CanCounters:
    frames_sent: int = 0
    send_errors: int = 0
    #: Scheduled cycles skipped because the loop was held up longer than a period.
    cycles_late: int = 0
    #: Commands passed to on_command that it carried out.
    commands_accepted: int = 0
    #: Commands passed to on_command that it declined (or that raised).
    commands_declined: int = 0
    #: Command frames refused before on_command: disabled, CRC, counter, code, length.
    commands_rejected: int = 0


BusFactory = Callable[..., can.BusABC]

#: A sender that restarted is back in step when its next frame, one counter ahead of a
#: refused one, comes within this long (a PLC resends an unacknowledged command within
#: a few cycles; a replayed pair from long ago is not within it).
COMMAND_RESYNC_S = 1.0


class CanPublisher:
    """Sends ADXL_Position/ADXL_Velocity cyclically and serves ADXL_Command.

    Use from one asyncio event loop: `await start()`, `update(values)` as often as the
    daemon likes (the latest values are sent), `await stop()`.
    """

    def __init__(
        self,
        config: CanPublisherConfig,
        on_command: CommandCallback | None = None,
        bus_factory: BusFactory = can.Bus,
    ) -> None:
        self.config = config
        self._on_command = on_command
        self._bus_factory = bus_factory
        self._values: ValuesSource = NOTHING_PUBLISHED
        self.frames = config.frames
        self._encoder = CyclicEncoder(config.frames)
        # plain ints counted per frame; the frozen snapshot is made when asked for
        self._counts = {f.name: 0 for f in dataclasses.fields(CanCounters)}
        self._counters: CanCounters | None = CanCounters()
        self._alive = {frame.frame_id: 0 for frame in config.frames.cyclic}
        self._alive[config.frames.ack.frame_id] = 0
        self._last_command_counter: int | None = None
        # a refused frame's counter and time: the next frame one ahead of it within
        # COMMAND_RESYNC_S puts a restarted sender back in step
        self._resync_from: tuple[int, float] | None = None
        self._refused_log = PeerLogLimiter(log, config.refused_log_interval_s)
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._flush_timer: asyncio.TimerHandle | None = None
        self._running = False
        self._in_cycle = False  # building the values of a transmission (see update)
        self._period_s = config.period_ms / 1000.0
        self._min_interval_s = None if config.min_interval_ms is None else config.min_interval_ms / 1000.0
        # update() sends when the cycle is due (not in mixed mode: it has its own rule)
        self._sync = config.sync_to_updates and self._min_interval_s is None
        # how long after the due time the timer waits for an update() to send, and how
        # long before it an update() already sends (see the module doc)
        self._timer_lag_s = self._period_s / 2 if self._sync else 0.0
        self._early_s = self._period_s / 4 if self._sync else 0.0
        self._next_due = 0.0
        self._last_send = -float("inf")
        self._last_error_log = -float("inf")
        self._last_bug_log = -float("inf")
        self._errors_since_log = 0

    # ---------------------------------------------------------------- API --
    @property
    def counters(self) -> CanCounters:
        if self._counters is None:
            self._counters = CanCounters(**self._counts)
        return self._counters

    @property
    def send_errors(self) -> int:
        """counters.send_errors, without making a snapshot (read once per values build)."""
        return self._counts["send_errors"]

    @property
    def refused_commands(self) -> int:
        """counters.commands_rejected, without making a snapshot (read once per values build)."""
        return self._counts["commands_rejected"]

    @property
    def running(self) -> bool:
        return self._running

    def update(self, values: ValuesSource) -> None:
        """Hand over the newest values, or a function returning them, called only when
        a frame goes out (call in the event loop thread).

        May transmit them right here (see the module doc); never blocks.
        """
        self._values = values
        if not self._running or self._in_cycle:
            # (an update from inside a transmission — its values source drained newer
            # data — is already carried by it; it must not start a second one)
            return
        if self._sync:
            now = time.monotonic()
            if now >= self._next_due - self._early_s:
                self._transmit(now)
        elif self._min_interval_s is not None:
            now = time.monotonic()
            if now - self._last_send >= self._min_interval_s:
                try:
                    self._send_cycle(now)
                except Exception:  # as in _transmit
                    self._cycle_failed(now)
                self._next_due = now + self._period_s
                self._arm_timer()

    def update_due(self) -> bool:
        """Would `update()` transmit right now? For a caller that defers building its
        values until someone needs them: a due cycle (in step with the updates) or
        send-on-update is such a need; a strictly cyclic publisher reads the values
        when its own timer fires, so an update never is."""
        if not self._running:
            return False
        if self._sync:
            return time.monotonic() >= self._next_due - self._early_s
        if self._min_interval_s is not None:
            return time.monotonic() - self._last_send >= self._min_interval_s
        return False

    async def start(self) -> None:
        if self._bus is not None:
            raise CanPublisherError("CAN publisher already started")
        cfg = self.config
        try:
            self._bus = self._bus_factory(
                interface=cfg.interface,
                channel=cfg.channel,
                receive_own_messages=False,
                can_filters=[{"can_id": self.frames.command.frame_id, "can_mask": 0x7FF, "extended": False}],
                **({} if cfg.bitrate is None else {"bitrate": cfg.bitrate}),
                **cfg.bus_options,
            )
        except (can.CanError, OSError, ValueError, ImportError) as err:
            raise CanPublisherError(
                f"cannot open CAN bus {cfg.interface}:{cfg.channel}: {err}"
            ) from err
        loop = self._loop = asyncio.get_running_loop()
        # A bus with a descriptor (socketcan) is read from the loop; one without (virtual)
        # by a thread whose receive timeout is only how soon it notices stop(): each
        # timeout is a wakeup, so not too short (stop() waits for it, well within 1 s).
        self._notifier = can.Notifier(self._bus, [self._on_message], timeout=0.25, loop=loop)
        self._running = True
        self._next_due = time.monotonic()
        self._arm_timer()
        self._flush_timer = loop.call_later(cfg.refused_log_interval_s, self._flush_refused_log)
        log.info(
            "CAN publisher on %s:%s every %g ms%s", cfg.interface, cfg.channel, cfg.period_ms,
            f", also on update at most every {cfg.min_interval_ms:g} ms" if cfg.min_interval_ms is not None
            else ", in step with the updates" if cfg.sync_to_updates else "",
        )

    def _flush_refused_log(self) -> None:
        """The counts of refused frames held back, once per interval (see peer_log)."""
        self._refused_log.flush()
        self._flush_timer = self._loop.call_later(self.config.refused_log_interval_s, self._flush_refused_log)

    async def stop(self) -> None:
        self._running = False
        timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()
        flush, self._flush_timer = self._flush_timer, None
        if flush is not None:
            flush.cancel()
            self._refused_log.flush(everything=True)
        notifier, self._notifier = self._notifier, None
        if notifier is not None:
            # Joins the reader thread (if any) in an executor so the loop keeps going.
            await asyncio.get_running_loop().run_in_executor(None, notifier.stop, 1.0)
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    # ------------------------------------------------------------ internals --
    def _arm_timer(self) -> None:
        """(Re)schedule the timer for the next due time (plus the wait for an update)."""
        if self._timer is not None:
            self._timer.cancel()
        assert self._loop is not None
        # call_at on the loop's clock (time.monotonic for asyncio's loops): one call fewer
        # than call_later, at every transmission; a time in the past fires at once
        self._timer = self._loop.call_at(self._next_due + self._timer_lag_s, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        if self._running:
            self._transmit(time.monotonic())

    def _transmit(self, now: float) -> None:
        """The frames of the due cycle, then the next due time (drift-free, or resynced)."""
        try:
            self._send_cycle(now)
        except Exception:  # a bug in encoding: say so, skip this cycle, keep the schedule
            self._cycle_failed(now)
        self._next_due += self._period_s
        if self._next_due <= now:
            missed = int((now - self._next_due) / self._period_s) + 1
            self._bump(cycles_late=missed)
            self._next_due = now + self._period_s
        elif self._sync:
            # never sooner than half a period after this transmission; an update that
            # comes late in its window moves the schedule onto the updates' phase
            self._next_due = max(self._next_due, now + self._period_s - self._early_s)
        self._arm_timer()

    def _cycle_failed(self, now: float) -> None:
        if now - self._last_bug_log >= self.config.send_error_log_interval_s:
            log.exception("CAN cycle failed (logged at most every %g s)", self.config.send_error_log_interval_s)
            self._last_bug_log = now

    def _send_cycle(self, now: float) -> None:
        alive = self._alive
        frames = self.frames
        pos_id, vel_id, qual_id = frames.position.frame_id, frames.velocity.frame_id, frames.quality.frame_id
        self._in_cycle = True
        try:
            values = current(self._values)
        finally:
            self._in_cycle = False
        pos_payload, vel_payload, qual_payload = self._encoder.encode(values, alive[pos_id], alive[vel_id],
                                                                      alive[qual_id])
        self._send(pos_id, pos_payload)
        self._send(vel_id, vel_payload)
        self._send(qual_id, qual_payload)
        self._last_send = now

    def _send(self, frame_id: int, payload: bytes) -> None:
        # The counter advances per transmission attempt, so a receiver sees a gap where
        # a frame was lost, whatever the reason.
        self._alive[frame_id] = next_counter(self._alive[frame_id])
        message = can.Message(arbitration_id=frame_id, data=payload, is_extended_id=False)
        bus = self._bus
        if bus is None:
            return
        try:
            bus.send(message)
        except can.CanError as err:
            self._send_failed(err)
        except Exception as err:  # any driver failure: count it, keep the cycle alive
            self._send_failed(err, unexpected=True)
        else:
            self._counts["frames_sent"] += 1
            self._counters = None

    def _send_failed(self, err: Exception, unexpected: bool = False) -> None:
        self._bump(send_errors=1)
        self._errors_since_log += 1
        now = time.monotonic()
        if now - self._last_error_log >= self.config.send_error_log_interval_s:
            log.warning(
                "CAN send failed (%d failures since last report): %s",
                self._errors_since_log,
                err,
                exc_info=unexpected,
            )
            self._last_error_log = now
            self._errors_since_log = 0

    def _on_message(self, message: can.Message) -> None:
        """Notifier listener; runs in the event loop thread."""
        if (
            message.arbitration_id != self.frames.command.frame_id
            or message.is_extended_id
            or message.is_remote_frame
            or message.is_error_frame
        ):
            return
        frames = self.frames
        payload = bytes(message.data)
        check = check_command(payload, self._last_command_counter, frames)
        if check.problem is AckResult.COUNTER_ERROR:
            now = time.monotonic()
            resync = self._resync_from
            if resync is not None and now - resync[1] <= COMMAND_RESYNC_S:
                check = check_command(payload, resync[0], frames)  # one ahead of the refused one?
            self._resync_from = None if check.problem is None else (check.counter, now)
        if check.problem is None:
            self._last_command_counter = check.counter
            self._resync_from = None
        result = self._act(check)
        ack_id = frames.ack.frame_id
        self._send(ack_id, encode_ack(check, result, self._alive[ack_id], frames))

    def _act(self, check: CommandCheck) -> AckResult:
        if check.problem is not None or check.command is None:
            problem = check.problem or AckResult.UNKNOWN_COMMAND
            self._bump(commands_rejected=1)
            self._refused_log.note(f"CAN {self.config.channel}", problem.name,
                                   f"command frame refused: {problem.name} (code {check.code}, "
                                   f"counter {check.counter})")
            return problem
        if not self.config.commands_enabled or self._on_command is None:
            self._bump(commands_rejected=1)
            self._refused_log.note(f"CAN {self.config.channel}", "disabled",
                                   f"command {check.command.name} refused: commands over CAN are disabled")
            return AckResult.DISABLED
        source = f"can:{self.config.channel}"
        try:
            done = self._on_command(check.command, source)
        except Exception:
            log.exception("on_command(%s) from %s raised", check.command.name, source)
            self._bump(commands_declined=1)
            return AckResult.FAILED
        self._bump(commands_accepted=int(done), commands_declined=int(not done))
        # a hint comes every PLC cycle: one line per command, result and interval
        self._refused_log.note(f"CAN {self.config.channel}", f"{check.command.name} {done}",
                               f"command {check.command.name}: {'done' if done else 'declined'}", logging.INFO)
        return AckResult.DONE if done else AckResult.DECLINED

    def _bump(self, **deltas: int) -> None:
        for name, delta in deltas.items():
            self._counts[name] += delta
        self._counters = None
