"""The wires the daemon publishes on, as a list: Modbus, CAN, MQTT (Sparkplug B).

Each wire is one `Wire`: built from its typed settings (the driver's frozen dataclass,
made from its config section by `gateway/daemon/settings.py`; None where the section
says the wire is off), started, told when new values exist, given new settings on a
reload, stopped, and asked for its health. The supervisor holds a `WireSet` and loops
over it; it knows no wire by its kind except for the few numbers the status words
carry (`wires["can"].health()`, `wires["mqtt"].health()`). Adding an output is one
driver module, its config keys and its row in `WIRE_KINDS`.

Start: Modbus must come up (without it the daemon has no point: DeviceError); CAN that
cannot start is retried every CAN_RETRY_S in the background while Modbus serves; the
MQTT edge node connects, and reconnects, by itself. A reload changes only the wires
whose settings changed, all or nothing (`WireSet.apply`): each wire's own `apply`
leaves it as it was when it fails, and the wires already changed are given their old
settings back. Clients of a wire whose settings did not change stay connected.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import can

from drivers.can_publisher import BusFactory, CanPublisher, CanPublisherConfig, CanPublisherError
from drivers.modbus_server import ModbusServer, ModbusServerConfig, ModbusServerError
from drivers.published_values import CommandCallback, ValuesSource
from drivers.sparkplug_node import SparkplugNode
from drivers.sparkplug_settings import SparkplugError, SparkplugSettings
from gateway.config import Config
from gateway.daemon.settings import can_config_from, modbus_config_from, mqtt_settings_from
from gateway.errors import DeviceError

log = logging.getLogger("adxlgw")

CAN_RETRY_S = 5.0
STOP_TIMEOUT_S = 1.0


@dataclass(slots=True)  # not frozen: each wire keeps one and sets its fields when asked
class WireHealth:
    """What the status surfaces say of a wire (Modbus registers, CAN quality frame, log):
    a live record (the wire's one, brought up to date by `health()`, which the supervisor
    calls for every snapshot); read it when given, keep no reference."""

    name: str
    enabled: bool
    #: Serving (Modbus listening, CAN bus open, MQTT connected to its broker).
    up: bool
    #: Messages this wire could not send since start (CAN send errors, MQTT queue drops).
    dropped: int = 0
    #: Commands this wire refused since start (CAN: disabled, malformed, stale or replayed frames).
    refused: int = 0


@dataclass(frozen=True, slots=True)
class WireContext:
    """What every wire gets from the supervisor."""

    values: ValuesSource  # the newest snapshot, built only when a wire reads it
    on_command: CommandCallback
    before_read: Callable[[], None]  # take the bytes waiting in the board's port first
    can_bus_factory: BusFactory = can.Bus
    version: str = ""  # the gateway's version, for the wires that announce it


class Wire(Protocol):
    """One output. Every method runs in the event loop and returns quickly; `publish`
    runs once per batch of board samples (the 500 samples/s path) and must never wait."""

    name: str

    async def start(self) -> None:
        """Serving, or retrying by itself; DeviceError only where the daemon must not run without it."""

    def publish(self) -> None:
        """New values exist (read them through the context's values source when needed)."""

    async def apply(self, settings: Any) -> None:
        """Serve with these settings from now on — or DeviceError and everything as it was."""

    async def stop(self) -> None:
        """Idempotent; nothing left running."""

    def health(self) -> WireHealth:
        """As of now (the wire's one WireHealth, updated in place: asked for every snapshot)."""


async def stop_within_timeout(component) -> None:
    with contextlib.suppress(Exception):
        await asyncio.wait_for(component.stop(), timeout=STOP_TIMEOUT_S)


class ModbusWire:
    """The Modbus TCP (and RTU) server. A new address: the new server starts before the
    old one is let go; the same address: the old one comes back if the new one fails."""

    name = "modbus"

    def __init__(self, settings: ModbusServerConfig, ctx: WireContext):
        self.settings = settings
        self._ctx = ctx
        self.server: ModbusServer | None = None
        self._health = WireHealth(self.name, enabled=True, up=False)

    def _new_server(self, settings: ModbusServerConfig) -> ModbusServer:
        return ModbusServer(settings, on_command=self._ctx.on_command, before_read=self._ctx.before_read)

    async def start(self) -> None:
        server = self._new_server(self.settings)
        try:
            await server.start()
        except ModbusServerError as err:
            raise DeviceError(f"Modbus server: {err}") from err
        server.update(self._ctx.values)  # from the first read on, what the gateway knows
        self.server = server

    def publish(self) -> None:
        if self.server is not None:
            self.server.update(self._ctx.values)

    async def apply(self, settings: ModbusServerConfig) -> None:
        old, previous = self.settings, self.server
        same_place = (old.host, old.port, old.rtu_port) == (settings.host, settings.port, settings.rtu_port) \
            and settings.port != 0
        if same_place and previous is not None:
            await stop_within_timeout(previous)
        replacement = self._new_server(settings)
        try:
            await replacement.start()
        except ModbusServerError as err:
            if same_place and previous is not None:  # the old one back where it was
                restored = self._new_server(old)
                await restored.start()
                restored.update(self._ctx.values)
                self.server = restored
            raise DeviceError(f"Modbus server with the new settings: {err}") from err
        replacement.update(self._ctx.values)
        self.server, self.settings = replacement, settings
        if not same_place and previous is not None:
            await stop_within_timeout(previous)

    async def stop(self) -> None:
        if self.server is not None:
            await stop_within_timeout(self.server)
        self.server = None

    def health(self) -> WireHealth:
        self._health.up = self.server is not None
        return self._health


class CanWire:
    """The CAN publisher (None settings: off). A bus that cannot open at start is retried
    every CAN_RETRY_S while the other wires serve."""

    name = "can"

    def __init__(self, settings: CanPublisherConfig | None, ctx: WireContext):
        self.settings = settings
        self._ctx = ctx
        self.publisher: CanPublisher | None = None
        self.start_failures = 0
        self._retry: asyncio.Task | None = None
        self._health = WireHealth(self.name, enabled=False, up=False)

    async def _open(self, settings: CanPublisherConfig) -> CanPublisher:
        publisher = CanPublisher(settings, on_command=self._ctx.on_command, bus_factory=self._ctx.can_bus_factory)
        await publisher.start()
        publisher.update(self._ctx.values)
        return publisher

    async def start(self) -> None:
        if self.settings is None:
            return
        try:
            self.publisher = await self._open(self.settings)
        except CanPublisherError as err:
            self.start_failures += 1
            log.error("%s; retrying every %g s", err, CAN_RETRY_S)
            self._retry = asyncio.create_task(self._retry_open(self.settings), name="can-retry")

    async def _retry_open(self, settings: CanPublisherConfig) -> None:
        while self.publisher is None:
            await asyncio.sleep(CAN_RETRY_S)
            try:
                self.publisher = await self._open(settings)
                log.info("CAN publisher started")
            except CanPublisherError as err:
                self.start_failures += 1
                log.debug("%s", err)

    async def _cancel_retry(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
            await asyncio.gather(self._retry, return_exceptions=True)
            self._retry = None

    def publish(self) -> None:
        if self.publisher is not None:
            self.publisher.update(self._ctx.values)

    def update_due(self) -> bool:
        """A CAN cycle is due: the numbers are wanted now (see Gateway.receive)."""
        return self.publisher is not None and self.publisher.update_due()

    async def apply(self, settings: CanPublisherConfig | None) -> None:
        old = self.settings
        previous, self.publisher = self.publisher, None
        await self._cancel_retry()
        if previous is not None:
            # a CAN channel can have several users: the new one may start beside the old
            await stop_within_timeout(previous)
        if settings is None:
            self.settings = None
            return
        try:
            self.publisher = await self._open(settings)
        except CanPublisherError as err:
            if previous is not None:
                try:
                    await previous.start()
                    self.publisher = previous
                except CanPublisherError:
                    self._retry = asyncio.create_task(self._retry_open(old), name="can-retry")
            raise DeviceError(f"CAN with the new settings: {err}") from err
        self.settings = settings

    async def stop(self) -> None:
        await self._cancel_retry()
        if self.publisher is not None:
            await stop_within_timeout(self.publisher)
        self.publisher = None

    def health(self) -> WireHealth:
        p, health = self.publisher, self._health
        health.enabled, health.up = self.settings is not None, p is not None
        health.dropped = 0 if p is None else p.send_errors
        health.refused = 0 if p is None else p.refused_commands
        return health


class MqttWire:
    """The Sparkplug B edge node (None settings: off). It connects and reconnects by
    itself; a broker that is missing or refuses it never stops the other wires."""

    name = "mqtt"

    def __init__(self, settings: SparkplugSettings | None, ctx: WireContext):
        self.settings = settings
        self._ctx = ctx
        self.node: SparkplugNode | None = None
        self._health = WireHealth(self.name, enabled=False, up=False)

    def _new_node(self, settings: SparkplugSettings, first_bd_seq: int = 0) -> SparkplugNode:
        return SparkplugNode(settings, values=self._ctx.values, on_command=self._ctx.on_command,
                             version=self._ctx.version, first_bd_seq=first_bd_seq)

    async def _start_node(self, settings: SparkplugSettings, first_bd_seq: int) -> SparkplugNode:
        node = self._new_node(settings, first_bd_seq)
        try:
            await node.start()
        except SparkplugError as err:
            raise DeviceError(str(err)) from err
        return node

    async def start(self) -> None:
        if self.settings is not None:
            self.node = await self._start_node(self.settings, 0)

    def publish(self) -> None:
        if self.node is not None:
            # does anything only once per 1/rate_hz: MQTT rides on the daemon's wakeups
            self.node.poll()

    async def apply(self, settings: SparkplugSettings | None) -> None:
        # a new session either way: the old one says its NDEATH, the new one is born with
        # the next bdSeq; a new one that cannot start (its TLS file) gives the old one back
        old_settings, old_node = self.settings, self.node
        next_bd_seq = 0
        if old_node is not None:
            await stop_within_timeout(old_node)
            next_bd_seq = old_node.bd_seq + 1
        self.node = None
        try:
            if settings is not None:
                self.node = await self._start_node(settings, next_bd_seq)
        except DeviceError as err:
            if old_settings is not None:
                self.node = await self._start_node(old_settings, next_bd_seq)
            raise DeviceError(f"MQTT with the new settings: {err}") from err
        self.settings = settings

    async def stop(self) -> None:
        if self.node is not None:
            await stop_within_timeout(self.node)
        self.node = None

    def health(self) -> WireHealth:
        n, health = self.node, self._health
        health.enabled, health.up = self.settings is not None, n is not None and n.publishing
        health.dropped = 0 if n is None else n.counters.dropped
        return health


@dataclass(frozen=True)
class WireKind:
    """How a wire is made: its typed settings from the config, and its class."""

    settings_from: Callable[[Config], Any]
    build: Callable[[Any, WireContext], Wire]


#: Every output, in start order (Modbus first: it must come up).
WIRE_KINDS: tuple[WireKind, ...] = (
    WireKind(modbus_config_from, ModbusWire),
    WireKind(can_config_from, CanWire),
    WireKind(mqtt_settings_from, MqttWire),
)


class WireSet:
    """The daemon's wires, started and stopped together, reloaded all or nothing."""

    def __init__(self, cfg: Config, ctx: WireContext, kinds: tuple[WireKind, ...] = WIRE_KINDS):
        self._kinds = kinds
        self.wires: list[Wire] = [kind.build(kind.settings_from(cfg), ctx) for kind in kinds]
        self._by_name = {w.name: w for w in self.wires}
        self._due_checks = [w.update_due for w in self.wires if hasattr(w, "update_due")]

    def __getitem__(self, name: str) -> Wire:
        return self._by_name[name]

    async def start(self) -> None:
        started: list[Wire] = []
        try:
            for wire in self.wires:
                await wire.start()
                started.append(wire)
        except BaseException:
            for wire in reversed(started):
                await wire.stop()
            raise

    def published(self) -> None:
        """New values: each wire sends or serves them as its schedule says."""
        for wire in self.wires:
            wire.publish()

    def update_due(self) -> bool:
        """Some wire wants the numbers now (a CAN cycle is due)."""
        return any(due() for due in self._due_checks)

    async def apply(self, old: Config, new: Config) -> None:
        """Reload: the wires whose settings changed, with the new settings — or, when
        one cannot take them, DeviceError and every wire as it was."""
        changed: list[tuple[Wire, Any]] = []
        for kind, wire in zip(self._kinds, self.wires, strict=False):
            before, after = kind.settings_from(old), kind.settings_from(new)
            if before == after:
                continue
            try:
                await wire.apply(after)
            except DeviceError:
                for done, settings in reversed(changed):  # all or nothing: back to the old settings
                    try:
                        await done.apply(settings)
                    except DeviceError as err:
                        log.error("%s could not go back to its old settings: %s", done.name, err)
                raise
            changed.append((wire, before))

    async def stop(self) -> None:
        for wire in reversed(self.wires):
            await wire.stop()
