"""The gateway's supervisor: board (serial) → realtime estimator → its wires (Modbus, CAN, MQTT).

One asyncio task tree under one supervisor coroutine. Signals: SIGTERM/SIGINT stop
(cancel, then gather; well within 2 s), SIGHUP reloads the config. systemd hears
READY once the board's port is open and the servers listen, WATCHDOG only while
samples flow, STOPPING at the end.

The hot path is one event-loop callback per wakeup by the serial port
(`SerialSource.deliver` → `Gateway.receive`). The kernel wakes the process only once
`serial.batch_frames` SAMPLE frames' bytes have arrived (termios VMIN; 5 frames, 10 ms
at 500 samples/s), and whatever reads the values — a Modbus read, a CAN cycle, a
command, the view — first takes the bytes that came since (`SerialSource.read_pending`),
so no wire shows older numbers than with a wakeup per frame. Where the port cannot
batch (a pyserial URL, batch_frames = 1) the bytes are kept with their arrival time
until something needs the numbers or MAX_DEFER_S has passed. Either way a batch goes
through the sample pipeline (runs of SAMPLE frames in one compiled call,
gateway/daemon/sample_pipeline.py; events and snapshots in gateway/daemon/board_intake.py)
and published once (the values are built only when a Modbus read or a CAN frame needs
them); the CAN frames of a due cycle go out from inside that publish, locked onto the
wakeups (drivers/can_publisher.py). Nothing else wakes the process while samples flow:
the publishing tick is a timer that the batches keep pushing back, and fires only once
the board has been quiet for PUBLISH_TICK_S to 3 × PUBLISH_TICK_S (then every
PUBLISH_TICK_S).

`Gateway` inherits the SIGHUP reload (gateway/daemon/config_reload.py) and the background
tasks with the state they save (gateway/daemon/service_tasks.py).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import can

from drivers.can_publisher import BusFactory, CanPublisher
from drivers.modbus_identity import package_version
from drivers.modbus_server import ModbusServer
from drivers.published_values import Command, PublishedValues, StatusBits, StatusExtBits, flag_word
from drivers.sparkplug_node import SparkplugNode
from gateway.config import Config
from gateway.daemon.board_port import BoardPort
from gateway.daemon.config_reload import ConfigReload
from gateway.daemon.sd_notify import SystemdNotifier
from gateway.daemon.service_tasks import ServiceTasks
from gateway.daemon.settings import calibration_from, estimator_settings_from, model_terms_from
from gateway.daemon.state_store import PersistentState, StateStore, restored_position_std_m
from gateway.daemon.status_flags import GatewayCondition, LinkHealth, status_bits
from gateway.daemon.wires import WireContext, WireSet
from gateway.errors import DeviceError

if TYPE_CHECKING:
    # rich, behind the view, is an offline tool's library (pyproject's [offline]); the board
    # side (numpy, numba and its compiled code) is imported by Gateway.start, off the event loop
    from gateway.daemon.board_intake import BoardIntake
    from gateway.daemon.sample_pipeline import SamplePipeline
    from gateway.daemon.terminal_view import TerminalView

log = logging.getLogger("adxlgw")

PUBLISH_TICK_S = 0.01  # staleness, heartbeat and republishing while no samples come
# Received bytes wait at most this long (or this many chunks) before they are decoded
# and estimated, if nothing needs the numbers sooner (see Gateway.receive).
MAX_DEFER_S = PUBLISH_TICK_S
MAX_DEFER_CHUNKS = 64
# while samples flow, the quiet tick is kept this many ticks ahead (see _drain)
QUIET_AFTER_TICKS = 3
# the machine's standstill hints: the value each command sets
_HINTS = {Command.HINT_AT_REST: True, Command.HINT_MOVING: False, Command.HINT_UNKNOWN: None}


@dataclass
class Counters:
    config_reloads: int = 0
    config_reload_errors: int = 0
    watchdog_pings: int = 0


def _terminal_view() -> TerminalView:
    from gateway.daemon.terminal_view import TerminalView

    return TerminalView()


class Gateway(ServiceTasks, ConfigReload):
    """The supervisor. Use as an async context manager (`async with Gateway(cfg) as gw:`
    starts it, leaving the block stops it), or `await gw.run()` as the command does
    (signals: SIGTERM/SIGINT stop, SIGHUP reloads). `stop()` is idempotent."""

    def __init__(
        self,
        cfg: Config,
        *,
        reload: Callable[[], Config] | None = None,
        notifier: SystemdNotifier | None = None,
        clock: Callable[[], float] = time.monotonic,
        publish_tick_s: float = PUBLISH_TICK_S,
        can_bus_factory: BusFactory = can.Bus,
        view: TerminalView | None = None,
    ):
        self.cfg = cfg
        self._reload = reload
        self.notifier = notifier or SystemdNotifier()
        self.clock = clock
        self.publish_tick_s = publish_tick_s  # how often to republish while the board is quiet
        self.counters = Counters()
        self.state_store = StateStore(cfg.state.path, travel_m=tuple(cfg.estimator.travel_m))
        saved = self.state_store.load()
        #: start_at_rest believed: configured, and this is a first start (no state file) or
        #: the last run stopped in order while the axis stood. After a crash, kill -9 or
        #: watchdog abort the axis may be mid-move: the velocity is not known then.
        self.starts_at_rest = cfg.estimator.start_at_rest and (
            self.state_store.found_none or saved.stopped_at_rest_unix_s is not None)
        # what is on disk while this run lives: the same, minus the orderly-stop mark, so that
        # a crash or kill -9 from now on leaves a file that says so (written by start())
        self._state_while_running = replace(saved, stopped_at_rest_unix_s=None)
        if cfg.estimator.start_at_rest and not self.starts_at_rest:
            log.warning("estimator.start_at_rest not believed: the last run did not stop in order at rest "
                        "(a crash, a kill, a stop mid-move); position not trusted until a stop is seen")
        self._start_position_m = saved.last_position_m or 0.0
        #: the board side — bytes → estimates → snapshots —, built by start() off the event
        #: loop once the wires listen (None until then: the wires show `_starting_values`)
        self.pipeline: SamplePipeline | None = None
        self.intake: BoardIntake | None = None
        self._board_side_built = asyncio.Event()
        self._sensor_lag_s = math.nan  # the estimator's sensor lag as built (_build_board_side)
        # the restored position's σ is set at the first estimate: the axis was unwatched
        # until then (a board that comes late included), not only while the gateway was down
        # (a first start — no state file — has nothing to restore: its position starts at 0
        # by definition, unreferenced)
        self._restored: PersistentState | None = None if self.state_store.found_none else saved
        self._hint_until = math.inf  # when the machine's standstill hint expires
        self.board = BoardPort(lambda: self.cfg)
        self.wires = WireSet(cfg, WireContext(self.fresh_values, self.on_command, self._drain_now,
                                              can_bus_factory, version=package_version()))
        # the wires whose numbers the status words carry, their health asked for every snapshot
        self._can_health, self._mqtt_health = self.wires["can"].health, self.wires["mqtt"].health
        self.view = view if view is not None else (_terminal_view() if cfg.service.view else None)
        self._kernel_batches = False  # the port wakes us per batch of frames (see receive)
        self._port_just_read = False
        self._reloaded_at: float | None = None
        #: the links' state: one record, brought up to date in place at each snapshot read (_health)
        self._link_health = LinkHealth(port_open=False, last_byte_s=None, stale_after_s=math.inf,
                                       lost_after_s=math.inf)
        self._stop_requested = asyncio.Event()
        self._sigint = False
        self._ready = asyncio.Event()
        self._started = False
        self._stopped = False
        self._tasks: list[asyncio.Task] = []
        self._board_task: asyncio.Task | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tick_handle: asyncio.TimerHandle | None = None
        self._tick_due = -math.inf
        self._tick_failed = False
        self._last_saved_s = clock()
        self._state_dirty = False

    # ------------------------------------------------------------ lifecycle --
    async def __aenter__(self) -> Gateway:
        await self.start()
        return self

    async def __aexit__(self, *_exc_info: object) -> None:
        await self.stop()

    async def start(self) -> None:
        """Servers listening, then the board side built, the board port being opened
        (READY once it is: `wait_ready`).

        The wires first: a PLC polling a gateway that starts (after a crash too) gets an
        answer that says "nothing measured yet" (`_starting_values`) within a fraction of
        a second, instead of no connection for as long as numpy, numba and the compiled
        estimator take to load (a second or more: benchmarks/daemon/daemon_footprint.py). That
        load runs in a worker thread, so the event loop answers meanwhile."""
        if self._started:
            return
        self._started = True
        self._loop = asyncio.get_running_loop()
        await asyncio.to_thread(self.state_store.save, self._state_while_running)
        await self.wires.start()
        self.board.prepare()  # the emulated board's child starts meanwhile
        # a thread of its own, not the loop's default executor: asyncio.run waits for that one
        # at its end, and a stop must not wait for a build it no longer needs (run)
        builder = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="board-side")
        try:
            self.pipeline, self.intake = await self._loop.run_in_executor(builder, self._build_board_side, self.cfg)
        except BaseException:
            await self.wires.stop()
            await self.board.close()
            raise
        finally:
            builder.shutdown(wait=False)
        self._board_side_built.set()
        self._publish(self.clock())  # the wires' images were of the starting values
        self._arm_tick(self.clock(), self.publish_tick_s)
        self._tasks.append(asyncio.create_task(self._housekeeping_task(), name="housekeeping"))
        self._board_task = asyncio.create_task(self._board_supervisor(), name="board")

    def _build_board_side(self, cfg: Config) -> tuple[SamplePipeline, BoardIntake]:
        """The sample pipeline and its intake (in a worker thread: nothing here touches
        what the event loop uses). The last published position is where the estimate
        continues from, flagged NOT_REFERENCED (the axis may have moved while the gateway
        was down): a prior, not a fact."""
        from gateway.daemon.board_intake import BoardIntake
        from gateway.daemon.sample_pipeline import SamplePipeline

        settings = estimator_settings_from(cfg)
        # the lag the model's filter terms gave the estimator: fixed while it runs (reload)
        self._sensor_lag_s = settings.sensor_lag_s
        pipeline = SamplePipeline(calibration_from(cfg), settings, cfg.calibration.axis,
                                  start_position_m=self._start_position_m, start_at_rest=self.starts_at_rest,
                                  travel_m=tuple(cfg.estimator.travel_m), model_terms=model_terms_from(cfg))
        return pipeline, BoardIntake(pipeline)

    def _starting_values(self) -> PublishedValues:
        """What the wires show before the board side is built: nothing measured, nothing
        referenced, the board not read — the bits a gateway whose port is still closed
        shows (POSITION_UNTRUSTED too unless the axis is believed to start at rest)."""
        serial = self.cfg.serial
        condition = GatewayCondition(now_s=self.clock(), have_estimate=False, port_open=False, last_sample_s=None,
                                     last_byte_s=None, stale_after_s=serial.stale_after_ms / 1000,
                                     lost_after_s=serial.lost_after_ms / 1000, referenced=False,
                                     untrusted=not self.starts_at_rest)
        simulated = StatusExtBits.SIMULATED if serial.port == "emulated" else 0
        return PublishedValues(status=status_bits(condition), status_ext=flag_word(StatusExtBits, int(simulated)))

    @property
    def ready(self) -> bool:
        """The board's port is open and the servers listen (systemd has heard READY)."""
        return self._ready.is_set()

    async def wait_ready(self, timeout_s: float | None = None) -> None:
        """Until READY; a board supervisor that failed raises its error here."""
        waiter = asyncio.create_task(self._ready.wait())
        try:
            done, _ = await asyncio.wait({waiter, self._board_task}, timeout=timeout_s,
                                         return_when=asyncio.FIRST_COMPLETED)
        finally:
            waiter.cancel()
        if self._board_task in done and not self.ready:
            self._board_task.result()
            raise DeviceError("the board supervisor ended before READY")
        if not done:
            raise TimeoutError(f"not ready within {timeout_s} s")

    def request_stop(self) -> None:
        """Ask `run` to stop (what SIGTERM does)."""
        self._stop_requested.set()

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGTERM, self.request_stop)
        loop.add_signal_handler(signal.SIGINT, self._interrupted)
        loop.add_signal_handler(signal.SIGHUP, lambda: self._tasks.append(asyncio.create_task(self._reload_logged())))
        stopper = asyncio.create_task(self._stop_requested.wait())
        # a stop while the estimator loads (seconds; minutes when numba compiles into an
        # empty cache) does not wait for it: the unit's TimeoutStopSec is 2 s
        starting = asyncio.create_task(self.start())
        try:
            await asyncio.wait({stopper, starting}, return_when=asyncio.FIRST_COMPLETED)
            if starting.done():
                starting.result()  # a start that failed raises here
                await asyncio.wait({stopper, self._board_task}, return_when=asyncio.FIRST_COMPLETED)
                if self._board_task.done() and not self._board_task.cancelled() and self._board_task.exception():
                    raise self._board_task.exception()
        finally:
            stopper.cancel()
            if not starting.done():
                starting.cancel()
                await asyncio.gather(starting, return_exceptions=True)
            await self.stop()
        # Ctrl-C is "interrupted" (exit 130, the README's table); SIGTERM an orderly stop (0)
        return 130 if self._sigint else 0

    def _interrupted(self) -> None:
        self._sigint = True
        self.request_stop()

    async def stop(self) -> None:
        """Cancel, then gather; close the port and servers; save the state."""
        if not self._started or self._stopped:
            return
        self._stopped = True
        self.notifier.stopping()
        tick, self._tick_handle = self._tick_handle, None
        if tick is not None:
            tick.cancel()
        tasks = [t for t in [*self._tasks, self._board_task] if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        final = self._state_to_save(stopping=True)  # while the port is open: its status is the axis'
        await self.wires.stop()
        await self.board.close()
        self.state_store.save(final)
        log.info("stopped")

    @property
    def modbus(self) -> ModbusServer | None:
        return self.wires["modbus"].server

    @property
    def can(self) -> CanPublisher | None:
        return self.wires["can"].publisher

    @property
    def mqtt(self) -> SparkplugNode | None:
        return self.wires["mqtt"].node

    # ------------------------------------------------------------- commands --
    def on_command(self, command: Command, source: str) -> bool:
        if self.pipeline is None:
            log.warning("%s from %s declined: the gateway is starting", command.name.lower(), source)
            return False
        self._drain(self.clock())  # act on the newest estimate
        if command == Command.TARE:
            if self.fresh_values().status & (StatusBits.STALE | StatusBits.BOARD_LOST):
                # the position is of a moment ago, and the axis may have moved since
                log.warning("tare from %s declined: the board's data is stale", source)
                return False
            if not self.pipeline.tare():
                log.warning("tare from %s declined: no estimate yet", source)
                return False
            self._state_dirty = True
            log.info("tare from %s: position := 0", source)
            self._publish(self.clock())  # the reply's next read already shows it
            return True
        if command in _HINTS:
            # the machine's word on the axis, until it is said again or times out
            self.pipeline.set_hint(_HINTS[command])
            self._hint_until = self.clock() + self.cfg.estimator.hint_timeout_ms / 1000
            return True
        if command == Command.REESTIMATE_BIAS:
            ok = self.pipeline.request_bias_reestimate()
            log.info("bias re-estimation from %s: %s", source, "accepted" if ok else "declined (not at standstill)")
            return ok
        return False

    # ------------------------------------------------------------- hot path --
    def receive(self, data: bytes) -> None:
        """Bytes from the board as they arrive (the serial port's reader callback).

        Where the kernel batches them (serial.batch_frames > 1 on a tty) each wakeup
        is one batch, handled now. Else they wait, with their arrival time, until
        something needs the numbers — a Modbus read, a due CAN cycle, a command, the
        view, the state file — or until the oldest has waited MAX_DEFER_S. Nothing a
        wire shows changes: every reader drains first, and each sample keeps the time
        the gateway got it. Why: on a VM the work after each wakeup runs cold, and
        at 500 samples/s a wakeup per sample was most of the daemon's CPU
        (benchmarks/daemon/wakeup_cost.py, docs/daemon.md).
        """
        now = self.clock()
        intake = self.intake
        intake.receive(now, data)
        if (self._kernel_batches or now - intake.waiting_since_s >= MAX_DEFER_S
                or intake.waiting_chunks >= MAX_DEFER_CHUNKS or self.wires.update_due()):
            # the port was just read dry: the CAN cycle's values need not read it again
            self._port_just_read = True
            try:
                self._drain(now, take_waiting=False)
            finally:
                self._port_just_read = False

    def _drain(self, now: float, take_waiting: bool = True) -> None:
        """Everything received so far through the pipeline, then one publish.

        With `take_waiting`, first the bytes waiting in the serial port (arrived since
        its last wakeup). One publish per batch, not per sample: the newest estimate
        is what every wire shows (saturation and lost samples are held for a while, so
        none is missed).
        """
        if self.intake is None:
            return  # starting: nothing received yet (the port opens after the board side is built)
        if now > self._hint_until:
            self.pipeline.set_hint(None)  # expired: the accelerometer alone decides again
            self._hint_until = math.inf
            log.info("standstill hint expired (no new hint within estimator.hint_timeout_ms)")
        if take_waiting:
            waiting = self.board.read_pending()
            if waiting:
                self.intake.receive(self.clock(), waiting)
        intake = self.intake
        if intake.drain():
            if self._restored is not None:
                self._set_restored_uncertainty()
            # as of the newest sample's arrival, as if each chunk had been handled then
            # (_publish written out: this runs at every wakeup)
            intake.publish(intake.events.last_sample_s)
            self.wires.published()
            # push the quiet tick back once less than a tick is left, to three ticks ahead:
            # about every second batch at 500 samples/s, not every one (re-arming an
            # asyncio timer is a dozen calls); it fires 1–3 ticks after the last sample
            if self._tick_handle is not None and self._tick_due - now < self.publish_tick_s:
                self._arm_tick(now, QUIET_AFTER_TICKS * self.publish_tick_s)

    def _set_restored_uncertainty(self) -> None:
        """Once, at the first estimate: the restored position's σ (state_store.restored_position_std_m)."""
        if self.pipeline.latest() is None:
            return
        saved, self._restored = self._restored, None
        est = self.cfg.estimator
        std_m = restored_position_std_m(saved, time.time(), self.pipeline.estimator.settings.restart_speed_std_mps,
                                        tuple(est.travel_m), est.still_while_down)
        self.pipeline.set_start_uncertainty(std_m)
        log.info("restored position %s m, σ %.3f m (saved %s s before the first sample)",
                 "unknown" if saved.last_position_m is None else f"{saved.last_position_m:.4f}", std_m,
                 "?" if saved.saved_at_unix_s is None else f"{time.time() - saved.saved_at_unix_s:.1f}")

    def _publish(self, now: float) -> None:
        """New values as of `now`: the heartbeat moves and every wire will show them
        (the snapshot is built only when a Modbus read or a CAN frame needs it)."""
        self.intake.publish(now)
        self.wires.published()

    def fresh_values(self) -> PublishedValues:
        """What the wires show, after everything received so far — the bytes waiting in
        the port included — went through the pipeline. Every reader calls this."""
        if self.intake is None:
            return self._starting_values()
        if not self._port_just_read:  # (else: asked from inside receive's drain, which took everything)
            self._drain(self.clock())
        return self.intake.snapshot(self._health())

    def _health(self) -> LinkHealth:
        """The links' state as of now: the one record, its fields set in place — not a new
        record (and two wire records) per snapshot: the MQTT node reads a snapshot rate_hz
        times a second, on a VM cold at each wakeup, and building them was an eighth of
        its tick (docs/decisions/0154). Readers take its numbers when they get it and
        keep no reference to it (BoardIntake builds the snapshot from it at once)."""
        health = self._link_health
        source = self.board.source  # (the port itself: read per snapshot, one hop fewer)
        serial = self.cfg.serial
        can, mqtt = self._can_health(), self._mqtt_health()
        health.port_open = source is not None and source.is_open
        health.last_byte_s = None if source is None else source.last_data_monotonic_s
        health.stale_after_s = serial.stale_after_ms / 1000
        health.lost_after_s = serial.lost_after_ms / 1000
        health.config_reloaded_at_s = self._reloaded_at
        health.can_send_errors, health.can_refused_commands = can.dropped, can.refused
        health.mqtt_down = mqtt.enabled and not mqtt.up
        health.mqtt_dropped = mqtt.dropped
        health.simulated = serial.port == "emulated"
        return health

    def _drain_now(self) -> None:
        self._drain(self.clock())

    def _arm_tick(self, now: float, delay: float | None = None) -> None:
        """(Re)schedule the quiet tick `delay` (default two ticks) from now.

        While samples flow, a batch pushes it back to QUIET_AFTER_TICKS ticks ahead once
        less than one is left, so it fires 1–3 ticks after the last sample without
        waking the process while samples flow.
        """
        if delay is None:
            delay = 2 * self.publish_tick_s
        if self._tick_handle is not None:
            self._tick_handle.cancel()
        self._tick_due = now + delay
        # (call_at on the loop's clock, time.monotonic: one call fewer than call_later)
        self._tick_handle = self._loop.call_at(time.monotonic() + delay, self._quiet_tick)

    def _quiet_tick(self) -> None:
        """While no samples come: publish every tick, so the heartbeat, the sample age
        and the STALE/BOARD_LOST bits keep moving (on Modbus and CAN)."""
        self._tick_handle = None
        now = self.clock()
        try:
            self._drain(now)
            self._publish(now)
        except Exception:
            if not self._tick_failed:  # a bug; say it once, keep ticking
                log.exception("publishing tick failed")
                self._tick_failed = True
        finally:
            if self._tick_handle is None and not self._stopped:
                self._arm_tick(now, self.publish_tick_s)
