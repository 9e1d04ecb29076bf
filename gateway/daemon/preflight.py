"""What `adxlgw run` checks before it starts, and `adxlgw config --check` reports.

The schema (gateway/config.py) decides what a value may be; these checks ask the
machine: is the board's port set and there, does the drift-model file load, does the
Modbus host resolve, does the CAN interface exist. Each finding names its key.

Severity says what `run` does with it:
  "error"  — run refuses to start (exit 2): no setting could make it work.
  "device" — run starts and waits for it (the board's port is retried with back-off,
             CAN every 5 s): a USB adapter may be plugged in later. `config --check`
             still fails on it, so a fresh install shows what is missing.
  "note"   — nothing wrong, but worth knowing (simulated values, unchecked URL).
"""
from __future__ import annotations

import socket
from dataclasses import dataclass

from drivers.link_checks import check_can_link, check_serial_port
from gateway.config import Config
from gateway.drift_model_file import load_drift_model
from gateway.errors import ConfigError, InputError

EMULATED = "emulated"


@dataclass(frozen=True)
class Finding:
    key: str
    severity: str  # "error", "device", "note"
    text: str

    def line(self, source: str) -> str:
        return f"{source}: {self.key}: {self.text}"


_SEVERITY_OF = {"missing": "device", "invalid": "error", "unchecked": "note"}


def findings(cfg: Config) -> list[Finding]:
    found: list[Finding] = []
    port = cfg.serial.port
    if port is None:
        found.append(Finding("serial.port", "error",
                             "not set: set it to the board's serial device (e.g. /dev/ttyUSB0 or "
                             "/dev/serial/by-id/…), or to \"emulated\" for the built-in virtual board"))
    elif port == EMULATED:
        found.append(Finding("serial.port", "note", "the built-in emulated board: every value is simulated"))
    else:
        found += _link("serial.port", check_serial_port(port))
    if cfg.estimator.drift_model:
        try:
            load_drift_model(cfg.estimator.drift_model)
        except InputError as err:
            found.append(Finding("estimator.drift_model", "error", str(err)))
    if cfg.modbus.tcp_enabled:
        try:
            socket.getaddrinfo(cfg.modbus.host, cfg.modbus.port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        except (socket.gaierror, UnicodeError) as err:
            found.append(Finding("modbus.host", "error", f"{cfg.modbus.host!r} does not resolve ({err})"))
    if cfg.modbus.rtu_enabled:
        found += _link("modbus.rtu_port", check_serial_port(cfg.modbus.rtu_port))
    if cfg.can.enabled:
        link = check_can_link(cfg.can.interface, cfg.can.channel)
        found += _link("can.interface" if link.wrong_interface else "can.channel", link)
    return found


def _link(key: str, check) -> list[Finding]:
    if check.verdict == "ok":
        return [Finding(key, "note", check.detail)] if check.detail else []
    return [Finding(key, _SEVERITY_OF[check.verdict], check.detail)]


def refuse_unrunnable(cfg: Config) -> list[Finding]:
    """Raise ConfigError (exit 2) on the first finding `run` cannot start with; return the rest."""
    found = findings(cfg)
    for finding in found:
        if finding.severity == "error":
            raise ConfigError(finding.line(cfg.source))
    return found
