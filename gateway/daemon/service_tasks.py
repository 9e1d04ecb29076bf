"""The background tasks of `Gateway` (gateway/daemon/supervisor.py) and the state they save:
the board supervisor (open the port, READY, serve it), the housekeeping (terminal view,
state saved when it changed or every STATE_SAVE_EVERY_S) and systemd's watchdog.

A mixin: `Gateway` inherits these methods; they use its state (cfg, board, pipeline,
intake, notifier, counters) as their own.
"""
from __future__ import annotations

import asyncio
import logging
import math
import time

from drivers.published_values import StatusBits
from gateway.daemon.state_store import PersistentState

log = logging.getLogger("adxlgw")

HOUSEKEEPING_S = 0.25  # terminal view, state save when something changed
STATE_SAVE_EVERY_S = 60.0


def board_alive_for_watchdog(now_s: float, last_sample_s: float | None, check_every_s: float,
                             lost_after_s: float) -> bool:
    """Feed systemd's watchdog at this check? The watchdog asks "is the service making
    progress?", so yes when a sample arrived since the previous check (one check per
    WatchdogSec/2): a hung board or a blocked loop gives no ping for a whole WatchdogSec and
    systemd restarts the unit. lost_after_s (serial.lost_after_ms) judges the freshness of
    the published values (STALE), not liveness: a board whose bytes come in bursts further
    apart than it (a starved CPU: 2.6-3.6 s gaps seen under qemu) is slow, not hung; it
    still counts when it is the longer of the two."""
    return last_sample_s is not None and now_s - last_sample_s < max(check_every_s, lost_after_s)


class ServiceTasks:
    """The tasks and the state saving, for `Gateway`."""

    # ---------------------------------------------------------------- state --
    def _state_to_save(self, stopping: bool = False) -> PersistentState:
        if self.pipeline is None:  # stopped while starting: nothing seen, the file stays as it was
            return self._state_while_running
        values = self.fresh_values()
        est = self.pipeline.latest()
        now = time.time()
        # at rest on evidence: a standstill the estimator trusts, the board's data fresh
        at_rest = bool(est is not None and est.standstill and not est.untrusted
                       and not values.status & (StatusBits.STALE | StatusBits.BOARD_LOST))
        return PersistentState(
            tare_offset_m=self.pipeline.reference_offset_m,
            bias_estimate_mps2=None if est is None or not math.isfinite(est.bias_mps2) else est.bias_mps2,
            last_position_m=values.position_m if math.isfinite(values.position_m) else None,
            saved_at_unix_s=now,
            stopped_at_rest_unix_s=now if stopping and at_rest else None,
        )

    async def _save_state(self) -> None:
        # fsyncs take milliseconds to seconds on a busy disk: not on the event loop
        state = self._state_to_save()
        self._state_dirty = False
        self._last_saved_s = self.clock()
        await asyncio.to_thread(self.state_store.save, state)

    # ---------------------------------------------------------------- tasks --
    def _receive_from_port(self, batched: bool, data: bytes) -> None:
        self._kernel_batches = batched  # per open port: a reopened one may not batch
        self.receive(data)

    async def _board_supervisor(self) -> None:
        """Open the port (READY then), read it, reopen it when a reload asks."""
        await self.board.open()
        self._tasks.append(asyncio.create_task(self._watchdog_task(), name="watchdog"))
        self.notifier.ready(f"board {self.board.path}; modbus {self.cfg.modbus.host}:{self.modbus.tcp_port}")
        self._ready.set()
        log.info("ready: board %s, Modbus TCP %s:%s, CAN %s, MQTT %s", self.board.path, self.cfg.modbus.host,
                 self.modbus.tcp_port, f"{self.cfg.can.interface}:{self.cfg.can.channel}" if self.can else "off",
                 self.mqtt.where if self.mqtt else "off")
        await self.board.serve(self._receive_from_port)

    async def _housekeeping_task(self) -> None:
        while True:
            await asyncio.sleep(HOUSEKEEPING_S)
            now = self.clock()
            if self.view:
                self.view.draw(self.fresh_values(), self._view_extra())
            if self._state_dirty or now - self._last_saved_s >= STATE_SAVE_EVERY_S:
                await self._save_state()

    def _view_extra(self) -> str:
        parts = [f"board {self.board.path or 'not open yet'}"]
        if self.modbus and self.modbus.tcp_port:
            parts.append(f"modbus tcp {self.cfg.modbus.host}:{self.modbus.tcp_port}")
        if self.can:
            parts.append(f"can {self.cfg.can.interface}:{self.cfg.can.channel} "
                         f"({self.can.counters.frames_sent} frames)")
        if self.mqtt:
            parts.append(f"mqtt {self.mqtt.where} ({'connected' if self.mqtt.connected else 'not connected'})")
        return "  ".join(parts)

    async def _watchdog_task(self) -> None:
        interval = self.notifier.watchdog_interval_s
        if not interval:
            return
        check_every_s = interval / 2
        while True:
            await asyncio.sleep(check_every_s)
            if board_alive_for_watchdog(self.clock(), self.intake.events.last_sample_s, check_every_s,
                                        self.cfg.serial.lost_after_ms / 1000):
                self.notifier.watchdog()
                self.counters.watchdog_pings += 1
