"""The wires the daemon publishes on: the Modbus server and the CAN publisher.

Started together (Modbus must come up: without it the daemon has no point; CAN that
cannot start is retried every CAN_RETRY_S in the background while Modbus serves) and
stopped together. A reload changes only the wire whose settings changed, all or
nothing (`apply`): the new server is started before the old one is let go where it
can be (another address or interface); where it must take the old one's place (same
address), the old one comes back if the new one fails. Clients of a wire whose settings
did not change stay connected.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Callable

import can

from drivers.can_publisher import BusFactory, CanPublisher, CanPublisherError
from drivers.modbus_server import ModbusServer, ModbusServerError
from drivers.published_values import CommandCallback, ValuesSource
from gateway.config import Config
from gateway.daemon.settings import can_config_from, modbus_config_from
from gateway.errors import DeviceError

log = logging.getLogger("adxlgw")

CAN_RETRY_S = 5.0
STOP_TIMEOUT_S = 1.0


class Wires:
    def __init__(self, values: ValuesSource, on_command: CommandCallback, before_read: Callable[[], None],
                 can_bus_factory: BusFactory = can.Bus):
        self._values = values  # every reader gets the numbers through this
        self._on_command = on_command
        self._before_read = before_read
        self._can_bus_factory = can_bus_factory
        self.modbus: ModbusServer | None = None
        self.can: CanPublisher | None = None
        self.can_start_failures = 0
        self._retry: asyncio.Task | None = None

    async def start(self, cfg: Config) -> None:
        """Modbus listening (DeviceError if it cannot), CAN started or being retried."""
        self.modbus = ModbusServer(modbus_config_from(cfg), on_command=self._on_command,
                                   before_read=self._before_read)
        try:
            await self.modbus.start()
        except ModbusServerError as err:
            self.modbus = None
            raise DeviceError(f"Modbus server: {err}") from err
        self.modbus.update(self._values)  # from the first read on, what the gateway knows
        if cfg.can.enabled:
            try:
                self.can = await self._start_can(cfg)
            except CanPublisherError as err:
                self.can_start_failures += 1
                log.error("%s; retrying every %g s", err, CAN_RETRY_S)
                self._retry = asyncio.create_task(self._retry_can(cfg), name="can-retry")

    async def _start_can(self, cfg: Config) -> CanPublisher:
        publisher = CanPublisher(can_config_from(cfg), on_command=self._on_command,
                                 bus_factory=self._can_bus_factory)
        await publisher.start()
        publisher.update(self._values)
        return publisher

    async def _retry_can(self, cfg: Config) -> None:
        while self.can is None:
            await asyncio.sleep(CAN_RETRY_S)
            try:
                self.can = await self._start_can(cfg)
                log.info("CAN publisher started")
            except CanPublisherError as err:
                self.can_start_failures += 1
                log.debug("%s", err)

    async def apply(self, old: Config, new: Config) -> None:
        """Reload: the wires whose settings changed, with the new settings — or, when a
        new one cannot start, DeviceError and everything as it was."""
        modbus_changed = old.modbus.as_tuple() != new.modbus.as_tuple()
        can_changed = old.can.as_tuple() != new.can.as_tuple()
        if modbus_changed:
            await self._replace_modbus(old, new)
        if can_changed:
            try:
                await self._replace_can(old, new)
            except DeviceError:
                if modbus_changed:  # all or nothing: Modbus back to the old settings
                    await self._replace_modbus(new, old)
                raise

    async def _replace_modbus(self, old: Config, new: Config) -> None:
        previous = self.modbus
        same_place = (old.modbus.host, old.modbus.port, old.modbus.rtu_port) == \
                     (new.modbus.host, new.modbus.port, new.modbus.rtu_port) and new.modbus.port != 0
        if same_place and previous is not None:
            await self._stop_one(previous)
        replacement = ModbusServer(modbus_config_from(new), on_command=self._on_command,
                                   before_read=self._before_read)
        try:
            await replacement.start()
        except ModbusServerError as err:
            if same_place and previous is not None:  # the old one back where it was
                restored = ModbusServer(modbus_config_from(old), on_command=self._on_command,
                                        before_read=self._before_read)
                await restored.start()
                restored.update(self._values)
                self.modbus = restored
            raise DeviceError(f"Modbus server with the new settings: {err}") from err
        replacement.update(self._values)
        self.modbus = replacement
        if not same_place and previous is not None:
            await self._stop_one(previous)

    async def _replace_can(self, old: Config, new: Config) -> None:
        previous, self.can = self.can, None
        if self._retry is not None:
            self._retry.cancel()
            await asyncio.gather(self._retry, return_exceptions=True)
            self._retry = None
        if previous is not None:
            # a CAN channel can have several users: the new one may start beside the old
            await self._stop_one(previous)
        if not new.can.enabled:
            return
        try:
            self.can = await self._start_can(new)
        except CanPublisherError as err:
            if previous is not None:
                try:
                    await previous.start()
                    self.can = previous
                except CanPublisherError:
                    self._retry = asyncio.create_task(self._retry_can(old), name="can-retry")
            raise DeviceError(f"CAN with the new settings: {err}") from err

    @staticmethod
    async def _stop_one(component) -> None:
        with contextlib.suppress(Exception):
            await asyncio.wait_for(component.stop(), timeout=STOP_TIMEOUT_S)

    def published(self) -> None:
        """New values: each wire sends or serves them as its schedule says."""
        if self.modbus is not None:
            self.modbus.update(self._values)
        if self.can is not None:
            self.can.update(self._values)

    async def stop(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
            await asyncio.gather(self._retry, return_exceptions=True)
            self._retry = None
        for component in (self.can, self.modbus):
            if component is not None:
                await self._stop_one(component)
        self.can = None
        self.modbus = None
