"""The gateway's supervisor: board (serial) → realtime estimator → Modbus and CAN.

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
until something needs the numbers or MAX_DEFER_S has passed. Either way a batch is
decoded and estimated (runs of SAMPLE frames in one compiled call,
gateway/sample_fast_path.py) and published once (the values are built only when a
Modbus read or a CAN frame needs them); the CAN frames of a due cycle go out from
inside that publish, locked onto the wakeups (drivers/can_publisher.py). Nothing else
wakes the process while samples flow: the publishing tick is a timer that the batches
keep pushing back, and fires only once the board has been quiet for PUBLISH_TICK_S to
2 × PUBLISH_TICK_S (then every PUBLISH_TICK_S).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import signal
import time
from dataclasses import dataclass, replace
from typing import Callable

from drivers.board_protocol import SAMPLE_FRAME_LENGTH, Hello, Sample, Status, StreamDecoder
from drivers.can_publisher import CanPublisher, CanPublisherConfig, CanPublisherError
from drivers.errors import SerialPortError
from drivers.modbus_server import ModbusServer, ModbusServerConfig, ModbusServerError
from drivers.published_values import Command, PublishedValues
from drivers.serial_source import SerialSettings, SerialSource, reconnect_delays_s
from gateway.board_session import BoardSession
from gateway.config import Config, load_config
from gateway.core.conversion import AxisCalibration, Calibration
from gateway.emulated_board import EmulatedBoard
from gateway.errors import ConfigError, DeviceError, InputError
from gateway.drift_model_file import load_drift_model
from gateway.estimation_link import EstimatorLink
from gateway.sample_fast_path import SampleFastPath
from gateway.sd_notify import SystemdNotifier
from gateway.state_store import PersistentState, StateStore
from gateway.status_flags import GatewayCondition, status_bits
from gateway.terminal_view import TerminalView

log = logging.getLogger("adxlgw")

PUBLISH_TICK_S = 0.01  # staleness, heartbeat and republishing while no samples come
# Received bytes wait at most this long (or this many chunks) before they are decoded
# and estimated, if nothing needs the numbers sooner (see Gateway.receive).
MAX_DEFER_S = PUBLISH_TICK_S
MAX_DEFER_CHUNKS = 64
HOUSEKEEPING_S = 0.25  # terminal view, periodic state save
SATURATION_HOLD_S = 1.0
STATE_SAVE_EVERY_S = 60.0


def calibration_from(cfg: Config) -> Calibration:
    c = cfg.calibration
    return Calibration(AxisCalibration(c.zero_g_duty_x, c.sensitivity_x),
                       AxisCalibration(c.zero_g_duty_y, c.sensitivity_y))


def modbus_config_from(cfg: Config) -> ModbusServerConfig:
    m = cfg.modbus
    return ModbusServerConfig(
        tcp_enabled=m.tcp_enabled, host=m.host, port=m.port, unit_id=m.unit_id, word_order=m.word_order,
        writes_enabled=m.writes_enabled, write_allow=tuple(m.write_allow), rtu_enabled=m.rtu_enabled,
        rtu_port=m.rtu_port, rtu_baudrate=m.rtu_baudrate, rtu_parity=m.rtu_parity,
        rtu_writes_enabled=m.rtu_writes_enabled,
    )


def can_config_from(cfg: Config) -> CanPublisherConfig:
    c = cfg.can
    return CanPublisherConfig(
        interface=c.interface, channel=c.channel,
        bitrate=None if c.interface == "socketcan" else c.bitrate,
        period_ms=float(c.period_ms),
        sync_to_updates=c.sync_to_updates,
        min_interval_ms=None if c.min_interval_ms < 0 else float(c.min_interval_ms),
        commands_enabled=c.commands_enabled,
    )


def batch_frames_for(cfg: Config) -> int:
    """How many SAMPLE frames wake the gateway: serial.batch_frames, but 1 when CAN
    sends a frame pair per sample (mixed mode), which needs a wakeup per sample."""
    return 1 if cfg.can.enabled and cfg.can.min_interval_ms >= 0 else cfg.serial.batch_frames


def serial_settings_from(cfg: Config, port: str) -> SerialSettings:
    s = cfg.serial
    return SerialSettings(port=port, baudrate=s.baudrate, reconnect_initial_s=s.reconnect_min_s,
                          reconnect_max_s=s.reconnect_max_s,
                          wake_min_bytes=batch_frames_for(cfg) * SAMPLE_FRAME_LENGTH)


def _arrival(batch: list[tuple[float, bytes]], byte_index: int) -> float:
    """Arrival time of the chunk that holds byte `byte_index` of the joined batch."""
    end = 0
    for arrived_s, chunk in batch:
        end += len(chunk)
        if byte_index < end:
            return arrived_s
    return batch[-1][0]


def _after(batch: list[tuple[float, bytes]], taken: int) -> list[tuple[float, bytes]]:
    """The batch without its first `taken` bytes (a chunk cut in two keeps its time)."""
    for k, (arrived_s, chunk) in enumerate(batch):
        if taken < len(chunk):
            return [(arrived_s, chunk[taken:])] + batch[k + 1:] if taken else batch[k:]
        taken -= len(chunk)
    return []


@dataclass
class Counters:
    samples: int = 0
    config_reloads: int = 0
    config_reload_errors: int = 0
    can_start_failures: int = 0
    watchdog_pings: int = 0


class Gateway:
    def __init__(
        self,
        cfg: Config,
        *,
        reload: Callable[[], Config] | None = None,
        notifier: SystemdNotifier | None = None,
        clock: Callable[[], float] = time.monotonic,
        compiled_samples: bool = True,
        view: TerminalView | None = None,
    ):
        self.cfg = cfg
        self._reload = reload
        self.notifier = notifier or SystemdNotifier()
        self.clock = clock
        self.counters = Counters()
        self.state_store = StateStore(cfg.state.path)
        self.saved = self.state_store.load()
        self.session = BoardSession(calibration_from(cfg), cfg.calibration.axis)
        drift = None
        if cfg.estimator.drift_model:
            try:
                drift = load_drift_model(cfg.estimator.drift_model)
            except InputError as err:
                raise ConfigError(f"{cfg.source}: estimator.drift_model: {err}") from err
        self.estimator = EstimatorLink(drift=drift, axis=cfg.calibration.axis)
        self.decoder = StreamDecoder()
        # SAMPLE frames by one compiled call per chunk when numba is there (same numbers)
        self._fast = (SampleFastPath(self.decoder, self.session, self.estimator)
                      if compiled_samples and SampleFastPath.available else None)
        self.source: SerialSource | None = None
        self.modbus: ModbusServer | None = None
        self.can: CanPublisher | None = None
        self.emulated: EmulatedBoard | None = None
        self.view = view if view is not None else (TerminalView() if cfg.service.view else None)
        # position reference: published = estimator position − offset
        self.reference_offset_m = -self.saved.last_position_m if self.saved.last_position_m else 0.0
        self.referenced = False  # after a restart, never trust an old reference
        self._inbox: list[tuple[float, bytes]] = []  # received, not yet decoded (see receive)
        self._kernel_batches = False  # the port wakes us per batch of frames (see receive)
        self._port_just_read = False
        self._values = PublishedValues()
        self._values_built = True  # False: published since, build on the next read
        self._published_at = clock()
        self._values_source = self._current_values  # handed to the publishers
        self._estimate = None
        self._last_sample_s: float | None = None
        self._saturated_until = -1.0
        self._board_reset_at: float | None = None
        self._lost_at: float | None = None
        self._reloaded_at: float | None = None
        self._heartbeat = 0
        self._stop = asyncio.Event()
        self._ready_sent = False
        self._serial_path: str | None = None
        self._tasks: list[asyncio.Task] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tick_handle: asyncio.TimerHandle | None = None
        self._tick_due = -math.inf
        self._tick_failed = False
        self._last_saved_s = clock()
        self._state_dirty = False

    # ------------------------------------------------------------- commands --
    def on_command(self, command: Command, source: str) -> bool:
        self._drain(self.clock())  # act on the newest estimate
        if command == Command.TARE:
            if self._estimate is None:
                log.warning("tare from %s declined: no estimate yet", source)
                return False
            self.reference_offset_m = self._estimate.pos_m
            self.referenced = True
            self._state_dirty = True
            log.info("tare from %s: position := 0", source)
            self.publish(self.clock())  # the reply's next read already shows it
            self._save_state()
            return True
        if command == Command.REESTIMATE_BIAS:
            ok = self.estimator.request_bias_reestimate(bool(self._estimate and self._estimate.standstill))
            log.info("bias re-estimation from %s: %s", source, "accepted" if ok else "declined (not at standstill)")
            return ok
        return False

    # --------------------------------------------------------------- frames --
    def receive(self, data: bytes) -> None:
        """Bytes from the board as they arrive (the serial port's reader callback).

        Where the kernel batches them (serial.batch_frames > 1 on a tty) each wakeup
        is one batch, handled now. Else they wait, with their arrival time, until
        something needs the numbers — a Modbus read, a due CAN cycle, a command, the
        view, the state file — or until the oldest has waited MAX_DEFER_S. Nothing a
        wire shows changes: every reader drains first, and each sample keeps the time
        the gateway got it. Why: on a VM the work after each wakeup runs cold, and
        at 500 samples/s a wakeup per sample was most of the daemon's CPU
        (benchmarks/wakeup_cost.py, docs/daemon.md).
        """
        now = self.clock()
        inbox = self._inbox
        inbox.append((now, data))
        if (self._kernel_batches or now - inbox[0][0] >= MAX_DEFER_S or len(inbox) >= MAX_DEFER_CHUNKS
                or (self.can is not None and self.can.update_due())):
            # the port was just read dry: the CAN cycle's values need not read it again
            self._port_just_read = True
            try:
                self._drain(now, take_waiting=False)
            finally:
                self._port_just_read = False

    def handle_frames(self, data: bytes) -> None:
        """Bytes from the board, handled now: every sample through the estimator, then
        one publish (what `receive` does for a batch)."""
        now = self.clock()
        self._inbox.append((now, data))
        self._drain(now, take_waiting=False)

    def _drain(self, now: float, take_waiting: bool = True) -> None:
        """Everything received so far through the estimator, then one publish.

        With `take_waiting`, first the bytes waiting in the serial port (arrived since
        its last wakeup). One publish per batch, not per sample: the newest estimate
        is what every wire shows (saturation and lost samples are held for a while, so
        none is missed).
        """
        if take_waiting and self.source is not None:
            waiting = self.source.read_pending()
            if waiting:
                self._inbox.append((self.clock(), waiting))
        batch, self._inbox = self._inbox, []
        if batch and self._ingest(batch):
            # as of the newest sample's arrival, as if each chunk had been handled then
            self.publish(self._last_sample_s)
            # push the quiet tick back, about once per tick (not per batch)
            if self._tick_handle is not None and self._tick_due - now < PUBLISH_TICK_S:
                self._arm_tick(now)

    def _ingest(self, batch: list[tuple[float, bytes]]) -> bool:
        """Decode and estimate (arrival time, bytes) chunks in order; True if any sample.

        Runs of whole SAMPLE frames go through the compiled path in one call (their
        chunks joined); whatever it does not take, chunk by chunk through the Python
        path. A sample's events carry the arrival time of the chunk its frame ended in.
        """
        sampled = False
        fast = self._fast
        while batch:
            if fast is not None and fast.ready:  # else joining the rest would be work for nothing
                data = batch[0][1] if len(batch) == 1 else b"".join([chunk for _, chunk in batch])
                taken = fast.take(data)
                if taken:
                    sampled = True
                    self.counters.samples += fast.samples
                    self._last_sample_s = _arrival(batch, taken - 1)
                    if fast.last_lost >= 0:
                        self._lost_at = _arrival(batch, (fast.last_lost + 1) * SAMPLE_FRAME_LENGTH - 1)
                    if fast.last_saturated >= 0:
                        self._saturated_until = (_arrival(batch, (fast.last_saturated + 1) * SAMPLE_FRAME_LENGTH - 1)
                                                 + SATURATION_HOLD_S)
                    self._estimate = self.estimator.latest(fast.entered_standstill)
                    batch = _after(batch, taken)
                    if not batch:
                        break
            now, data = batch[0]
            batch = batch[1:]
            sampled = self._ingest_frames(data, now) or sampled
        return sampled

    def _ingest_frames(self, data: bytes, now: float) -> bool:
        """One chunk through the Python path (StreamDecoder.feed, frame by frame)."""
        sampled = False
        for frame in self.decoder.feed(data):
            if isinstance(frame, Sample):
                sample = self.session.on_sample(frame)
                if sample is None:
                    continue
                self.counters.samples += 1
                sampled = True
                if sample.lost_before:
                    self._lost_at = now
                if sample.saturated:
                    self._saturated_until = now + SATURATION_HOLD_S
                self._estimate = self.estimator.step(sample.t_s, sample.acc_mps2, sample.lost_before)
            elif isinstance(frame, (Status, Hello)):
                if self.session.on_report(frame):
                    log.warning("board reset: continuity lost, position not referenced until the next tare")
                    self._board_reset_at = now
                    self._lose_reference()
        if sampled:
            self._last_sample_s = now
        return sampled

    def _lose_reference(self) -> None:
        if not self._values_built:
            self._build_values()  # the numbers published until now, kept while unreferenced
        if self._estimate is not None:
            # keep the published position continuous; it is just no longer trusted
            self.reference_offset_m -= self._estimate.pos_m
        self.estimator.reset()
        self._estimate = None
        self.referenced = False

    # -------------------------------------------------------------- publish --
    def condition(self, now: float) -> GatewayCondition:
        est = self._estimate
        source = self.source
        return GatewayCondition(
            now_s=now,
            have_estimate=est is not None,
            port_open=source is not None and source.is_open,
            last_sample_s=self._last_sample_s,
            last_byte_s=None if source is None else source.last_data_monotonic_s,
            stale_after_s=self.cfg.serial.stale_after_ms / 1000,
            lost_after_s=self.cfg.serial.lost_after_ms / 1000,
            referenced=self.referenced,
            standstill=bool(est and est.standstill),
            estimator_fault=bool(est and est.fault),
            holding=bool(est and (est.holding or est.initialising)),
            saturated_until_s=self._saturated_until,
            board_reset_at_s=self._board_reset_at,
            samples_lost_at_s=self._lost_at,
            config_reloaded_at_s=self._reloaded_at,
            bias_estimating=bool(est and est.bias_estimating),
        )

    def publish(self, now: float) -> None:
        """New values as of `now`: the heartbeat moves and every wire will show them.

        The snapshot itself is built only when something reads it (a Modbus read, a
        CAN transmission, `values`): per sample this is a few assignments.
        """
        self._heartbeat = (self._heartbeat + 1) & 0xFFFFFFFF
        self._published_at = now
        self._values_built = False
        if self.modbus:
            self.modbus.update(self._values_source)
        if self.can:
            self.can.update(self._values_source)

    @property
    def values(self) -> PublishedValues:
        """What the wires show: the snapshot of the last publish (after everything
        received so far, the bytes waiting in the port included, went through the
        estimator)."""
        self._drain(self.clock(), take_waiting=not self._port_just_read)
        if not self._values_built:
            self._build_values()
        return self._values

    def _current_values(self) -> PublishedValues:
        return self.values

    def _drain_now(self) -> None:
        self._drain(self.clock())

    def _build_values(self) -> None:
        now = self._published_at
        est = self._estimate
        c = self.decoder.live_counters
        if est is not None:
            pos = est.pos_m - self.reference_offset_m
            vel, acc, bias, pos_std = est.vel_mps, est.acc_mps2, est.bias_mps2, est.pos_std_m
        else:  # nothing estimated since start or reset: last published numbers, flagged
            last = self._values
            pos, vel, acc = last.position_m, last.velocity_mps, last.acceleration_mps2
            bias, pos_std = last.bias_estimate_mps2, last.position_std_m
        self._values_built = True
        self._values = PublishedValues(
            position_m=pos, velocity_mps=vel, acceleration_mps2=acc,
            status=status_bits(self.condition(now)),
            heartbeat=self._heartbeat,
            sample_counter=self.counters.samples,
            last_sample_age_ms=None if self._last_sample_s is None else (now - self._last_sample_s) * 1000,
            bias_estimate_mps2=bias, position_std_m=pos_std,
            board_temp_c=self.session.temp_c,
            lost_samples=c.samples_lost, crc_errors=c.crc_errors,
            board_resets=self.session.counters.resets_announced + self.session.counters.resets_inferred,
            can_send_errors=self.can.send_errors if self.can else 0,
        )

    # ---------------------------------------------------------------- state --
    def _save_state(self) -> None:
        self._drain(self.clock())
        est = self._estimate
        self.saved = PersistentState(
            tare_offset_m=self.reference_offset_m,
            bias_estimate_mps2=None if est is None or not math.isfinite(est.bias_mps2) else est.bias_mps2,
            last_position_m=None if not math.isfinite(self.values.position_m) else self.values.position_m,
            saved_at_unix_s=time.time(),
        )
        self.state_store.save(self.saved)
        self._last_saved_s = self.clock()
        self._state_dirty = False

    # ---------------------------------------------------------------- tasks --
    async def _open_board(self) -> None:
        port = self.cfg.serial.port
        if port == "emulated":
            self.emulated = EmulatedBoard()
            port = await self.emulated.start()
        self._serial_path = port
        self.source = SerialSource(serial_settings_from(self.cfg, port))
        delays = reconnect_delays_s(self.source.settings)
        while True:
            try:
                await asyncio.to_thread(self.source.open)
                log.info("board port %s open", port)
                return
            except SerialPortError as err:
                delay = next(delays)
                log.warning("%s; retrying in %.1f s", err, delay)
                await asyncio.sleep(delay)

    async def _board_task(self) -> None:
        # receive runs inside the loop's reader callback: no task switch per chunk
        await self.source.deliver(self._receive_from_port)

    def _receive_from_port(self, data: bytes) -> None:
        # known per open port (a reopened one may not batch), read per wakeup: cheap
        self._kernel_batches = self.source.wake_min_bytes > 1
        self.receive(data)

    def _arm_tick(self, now: float, delay: float = 2 * PUBLISH_TICK_S) -> None:
        """(Re)schedule the quiet tick `delay` from now.

        While samples flow, each chunk pushes it back to 2 ticks ahead once less than
        one is left, so it fires 10–20 ms after the last sample (as a plain 10 ms tick
        that skips when a sample came within the last 10 ms did), without waking the
        process while samples flow.
        """
        if self._tick_handle is not None:
            self._tick_handle.cancel()
        self._tick_due = now + delay
        self._tick_handle = self._loop.call_later(delay, self._quiet_tick)

    def _quiet_tick(self) -> None:
        """While no samples come: publish every PUBLISH_TICK_S, so the heartbeat, the
        sample age and the STALE/BOARD_LOST bits keep moving (on Modbus and CAN)."""
        self._tick_handle = None
        now = self.clock()
        try:
            self._drain(now)
            self.publish(now)
        except Exception:
            if not self._tick_failed:  # a bug; say it once, keep ticking
                log.exception("publishing tick failed")
                self._tick_failed = True
        finally:
            if self._tick_handle is None:
                self._arm_tick(now, PUBLISH_TICK_S)

    async def _housekeeping_task(self) -> None:
        while True:
            await asyncio.sleep(HOUSEKEEPING_S)
            now = self.clock()
            if self.view:
                self.view.draw(self.values, self._view_extra())
            if self._state_dirty or now - self._last_saved_s >= STATE_SAVE_EVERY_S:
                self._save_state()

    def _view_extra(self) -> str:
        parts = [f"board {self._serial_path}"]
        if self.modbus and self.modbus.tcp_port:
            parts.append(f"modbus tcp {self.cfg.modbus.host}:{self.modbus.tcp_port}")
        if self.can:
            parts.append(f"can {self.cfg.can.interface}:{self.cfg.can.channel} ({self.can.counters.frames_sent} frames)")
        return "  ".join(parts)

    async def _watchdog_task(self) -> None:
        interval = self.notifier.watchdog_interval_s
        if not interval:
            return
        while True:
            await asyncio.sleep(interval / 2)
            now = self.clock()
            flowing = self._last_sample_s is not None and now - self._last_sample_s < self.cfg.serial.lost_after_ms / 1000
            if flowing:  # a hung board must let systemd's watchdog fire
                self.notifier.watchdog()
                self.counters.watchdog_pings += 1

    async def _start_servers(self) -> None:
        # a read first takes the bytes waiting in the port (they may hold newer samples)
        self.modbus = ModbusServer(modbus_config_from(self.cfg), on_command=self.on_command,
                                   before_read=self._drain_now)
        try:
            await self.modbus.start()
        except ModbusServerError as err:
            raise DeviceError(f"Modbus server: {err}") from err
        if self.cfg.can.enabled:
            self.can = CanPublisher(can_config_from(self.cfg), on_command=self.on_command)
            try:
                await self.can.start()
            except CanPublisherError as err:
                # Modbus keeps serving; CAN is retried in the background
                self.counters.can_start_failures += 1
                log.error("%s; retrying every 5 s", err)
                self.can = None
                self._tasks.append(asyncio.create_task(self._retry_can(), name="can-retry"))

    async def _retry_can(self) -> None:
        while self.can is None:
            await asyncio.sleep(5)
            publisher = CanPublisher(can_config_from(self.cfg), on_command=self.on_command)
            try:
                await publisher.start()
                self.can = publisher
                log.info("CAN publisher started")
            except CanPublisherError as err:
                self.counters.can_start_failures += 1
                log.debug("%s", err)

    async def _stop_servers(self) -> None:
        for component in (self.can, self.modbus):
            if component is not None:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(component.stop(), timeout=1.0)
        self.can = None
        self.modbus = None

    async def reload(self) -> None:
        if self._reload is None:
            log.warning("SIGHUP: no config file to reload")
            return
        self.notifier.reloading()
        self._drain(self.clock())  # the bytes received so far, under the config they came with
        try:
            new = self._reload()
        except ConfigError as err:
            self.counters.config_reload_errors += 1
            log.error("reload refused, keeping the running config: %s", err)
            self.notifier.ready()
            return
        old, self.cfg = self.cfg, new
        self.counters.config_reloads += 1
        self._reloaded_at = self.clock()
        logging.getLogger().setLevel(new.service.log_level.upper())
        self.session.set_calibration(calibration_from(new), new.calibration.axis)
        if old.calibration.axis != new.calibration.axis:
            self._lose_reference()
        if old.modbus.as_tuple() != new.modbus.as_tuple() or old.can.as_tuple() != new.can.as_tuple():
            log.info("reload: restarting Modbus and CAN with the new settings")
            await self._stop_servers()
            await self._start_servers()
        if old.serial.as_tuple() != new.serial.as_tuple() or batch_frames_for(old) != batch_frames_for(new):
            log.info("reload: reopening the board port")
            self._restart_board = True
            self._board_runner.cancel()
        log.info("config reloaded from %s", new.source)
        self.notifier.ready()

    # ------------------------------------------------------------ supervisor --
    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGTERM, self._stop.set)
        loop.add_signal_handler(signal.SIGINT, self._stop.set)
        loop.add_signal_handler(signal.SIGHUP, lambda: self._tasks.append(asyncio.create_task(self.reload())))
        self._loop = loop
        try:
            await self._start_servers()
            self._arm_tick(self.clock(), PUBLISH_TICK_S)
            self._tasks.append(asyncio.create_task(self._housekeeping_task(), name="housekeeping"))
            opener = asyncio.create_task(self._open_board(), name="open-board")
            stopper = asyncio.create_task(self._stop.wait())
            await asyncio.wait({opener, stopper}, return_when=asyncio.FIRST_COMPLETED)
            if self._stop.is_set():
                opener.cancel()
                return 0
            stopper.cancel()
            self._tasks.append(asyncio.create_task(self._watchdog_task(), name="watchdog"))
            self.notifier.ready(f"board {self._serial_path}; modbus {self.cfg.modbus.host}:{self.modbus.tcp_port}")
            self._ready_sent = True
            log.info("ready: board %s, Modbus TCP %s:%s, CAN %s", self._serial_path, self.cfg.modbus.host,
                     self.modbus.tcp_port, f"{self.cfg.can.interface}:{self.cfg.can.channel}" if self.can else "off")
            while not self._stop.is_set():
                self._restart_board = False
                self._board_runner = asyncio.create_task(self._board_task(), name="board")
                stopper = asyncio.create_task(self._stop.wait())
                await asyncio.wait({self._board_runner, stopper}, return_when=asyncio.FIRST_COMPLETED)
                stopper.cancel()
                if self._board_runner.done() and not self._board_runner.cancelled():
                    exc = self._board_runner.exception()
                    if exc is not None:
                        log.error("board reader failed: %s", exc)
                if self._restart_board and not self._stop.is_set():
                    self._board_runner.cancel()
                    self.source.close()
                    await self._open_board()
                elif not self._stop.is_set():
                    await asyncio.sleep(1.0)  # reader ended unexpectedly: start it again
            return 0
        finally:
            self.notifier.stopping()
            await self._shutdown()

    async def _shutdown(self) -> None:
        tick, self._tick_handle = self._tick_handle, None
        if tick is not None:
            tick.cancel()
        runner = getattr(self, "_board_runner", None)
        tasks = [t for t in [*self._tasks, runner] if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self.source is not None:
            self.source.close()
        await self._stop_servers()
        if self.emulated is not None:
            await self.emulated.stop()
        self._save_state()
        log.info("stopped")
