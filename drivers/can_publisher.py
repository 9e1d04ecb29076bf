"""Cyclic CAN publisher of `PublishedValues`, and receiver of the command frame.

The cyclic frames are sent by our own asyncio loop on a monotonic schedule rather than
python-can's periodic tasks, because every transmission needs a new alive counter and
CRC. The schedule is drift-free (deadline += period); when the loop was blocked for
more than a period it resynchronises instead of sending a burst, and counts the lapse.

Optionally (`min_interval_ms`) `update()` also sends at once, at most that often, which
cuts the sample-to-frame latency below the cycle time; the cycle then restarts from
that transmission (AUTOSAR COM's "mixed" transmission mode).

A failed send (can.CanError: buffer full, bus off, interface down) is counted and
logged at a limited rate; the loop keeps going. Commands arrive through a python-can
Notifier; only frames that pass the E2E check are acted upon, and only when commands
are enabled. Every command frame is answered with an ADXL_CommandAck.
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
    ACK_FRAME,
    COMMAND_FRAME,
    CYCLIC_FRAMES,
    AckResult,
    CommandCheck,
    check_command,
    encode_ack,
    encode_cyclic,
    next_counter,
)
from .published_values import NOTHING_PUBLISHED, CommandCallback, PublishedValues

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
    #: None: purely cyclic. A number: update() also transmits at once when at least
    #: this long has passed since the last transmission.
    min_interval_ms: float | None = None
    #: Commands over CAN are refused (acknowledged as DISABLED) unless enabled.
    commands_enabled: bool = False
    #: Further keyword arguments for can.Bus (bitrate, fd, …).
    bus_options: Mapping[str, Any] = field(default_factory=dict)
    #: At most one log line per this interval about failing sends.
    send_error_log_interval_s: float = 10.0

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
        self._values = NOTHING_PUBLISHED
        self._counters = CanCounters()
        self._alive = {frame.frame_id: 0 for frame in CYCLIC_FRAMES}
        self._alive[ACK_FRAME.frame_id] = 0
        self._last_command_counter: int | None = None
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._task: asyncio.Task[None] | None = None
        self._period_s = config.period_ms / 1000.0
        self._min_interval_s = None if config.min_interval_ms is None else config.min_interval_ms / 1000.0
        self._next_due = 0.0
        self._last_send = -float("inf")
        self._last_error_log = -float("inf")
        self._errors_since_log = 0

    # ---------------------------------------------------------------- API --
    @property
    def counters(self) -> CanCounters:
        return self._counters

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def update(self, values: PublishedValues) -> None:
        """Hand over the newest values (call in the event loop thread)."""
        self._values = values
        if (
            self._min_interval_s is not None
            and self.running
            and time.monotonic() - self._last_send >= self._min_interval_s
        ):
            self._send_cycle()
            self._next_due = self._last_send + self._period_s

    async def start(self) -> None:
        if self._bus is not None:
            raise CanPublisherError("CAN publisher already started")
        cfg = self.config
        try:
            self._bus = self._bus_factory(
                interface=cfg.interface,
                channel=cfg.channel,
                receive_own_messages=False,
                can_filters=[{"can_id": COMMAND_FRAME.frame_id, "can_mask": 0x7FF, "extended": False}],
                **({} if cfg.bitrate is None else {"bitrate": cfg.bitrate}),
                **cfg.bus_options,
            )
        except (can.CanError, OSError, ValueError, ImportError) as err:
            raise CanPublisherError(
                f"cannot open CAN bus {cfg.interface}:{cfg.channel}: {err}"
            ) from err
        loop = asyncio.get_running_loop()
        # Short timeout: a thread-based reader (virtual bus) notices stop() quickly.
        self._notifier = can.Notifier(self._bus, [self._on_message], timeout=0.05, loop=loop)
        self._next_due = time.monotonic()
        self._task = asyncio.create_task(self._run(), name="can-publisher")
        log.info("CAN publisher on %s:%s every %g ms", cfg.interface, cfg.channel, cfg.period_ms)

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            try:
                await task
            except asyncio.CancelledError:
                pass
        notifier, self._notifier = self._notifier, None
        if notifier is not None:
            # Joins the reader thread (if any) in an executor so the loop keeps going.
            await asyncio.get_running_loop().run_in_executor(None, notifier.stop, 1.0)
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    # ------------------------------------------------------------ internals --
    async def _run(self) -> None:
        while True:
            delay = self._next_due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
                continue  # re-check: update() may have sent and moved the deadline
            self._send_cycle()
            self._next_due += self._period_s
            now = time.monotonic()
            if self._next_due <= now:
                missed = int((now - self._next_due) / self._period_s) + 1
                self._bump(cycles_late=missed)
                self._next_due = now + self._period_s

    def _send_cycle(self) -> None:
        counters = {frame.frame_id: self._alive[frame.frame_id] for frame in CYCLIC_FRAMES}
        for frame, payload in encode_cyclic(self._values, counters):
            self._send(frame.frame_id, payload)
        self._last_send = time.monotonic()

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
            self._bump(frames_sent=1)

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
            message.arbitration_id != COMMAND_FRAME.frame_id
            or message.is_extended_id
            or message.is_remote_frame
            or message.is_error_frame
        ):
            return
        check = check_command(bytes(message.data), self._last_command_counter)
        if check.problem is None:
            self._last_command_counter = check.counter
        result = self._act(check)
        self._send(ACK_FRAME.frame_id, encode_ack(check, result, self._alive[ACK_FRAME.frame_id]))

    def _act(self, check: CommandCheck) -> AckResult:
        if check.problem is not None or check.command is None:
            problem = check.problem or AckResult.UNKNOWN_COMMAND
            self._bump(commands_rejected=1)
            log.warning("CAN command frame refused: %s (code %d)", problem.name, check.code)
            return problem
        if not self.config.commands_enabled or self._on_command is None:
            self._bump(commands_rejected=1)
            log.warning("CAN command %s refused: commands over CAN are disabled", check.command.name)
            return AckResult.DISABLED
        source = f"can:{self.config.channel}"
        try:
            done = self._on_command(check.command, source)
        except Exception:
            log.exception("on_command(%s) from %s raised", check.command.name, source)
            self._bump(commands_declined=1)
            return AckResult.FAILED
        self._bump(commands_accepted=int(done), commands_declined=int(not done))
        log.info("CAN command %s: %s", check.command.name, "done" if done else "declined")
        return AckResult.DONE if done else AckResult.DECLINED

    def _bump(self, **deltas: int) -> None:
        c = self._counters
        self._counters = dataclasses.replace(
            c, **{name: getattr(c, name) + delta for name, delta in deltas.items()}
        )
