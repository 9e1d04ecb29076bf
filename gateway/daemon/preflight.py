"""What `adxlgw run` checks before it starts, and `adxlgw config --check` reports.

The schema (gateway/config.py) decides what a value may be; these checks ask the
machine: is the board's port set and there, do the drift-model and sensor-model files load, does the
Modbus host resolve, does the CAN interface exist. Each finding names its key.

One function, `findings`, for both callers: `config --check` fails on exactly what
`run` would refuse or wait for (the same verdict on the same file), and a reload
(SIGHUP) is checked by it too, against the running config.

Severity says what `run` does with it:
  "error"    — run refuses to start (exit 2): the config is wrong (a port not set, a
               Modbus host that is not an address of this machine).
  "unusable" — run refuses to start (exit 3): the device or port is there but cannot
               be used now (the Modbus TCP port taken or privileged).
  "device"   — run starts and waits for it (the board's port is retried with back-off,
               CAN every 5 s): a USB adapter may be plugged in later. `config --check`
               still fails on it, so a fresh install shows what is missing.
  "note"     — nothing wrong, but worth knowing (simulated values, unchecked URL).

A reload is all or nothing: any finding but a note on a wire the reload changes (a
missing serial port included) refuses it and the running config stays; wires it leaves
as they are are not checked again (the running daemon holds them).
"""
from __future__ import annotations

import importlib.util
import socket
from dataclasses import dataclass

from drivers.link_checks import check_can_link, check_serial_port
from drivers.modbus_ports import tcp_listen_check
from drivers.sparkplug_settings import tls_ca_problem
from gateway.config import Config
from gateway.daemon.settings import load_sample_path_model, read_credentials
from gateway.errors import ConfigError, DeviceError, InputError

EMULATED = "emulated"


@dataclass(frozen=True)
class Finding:
    key: str
    severity: str  # "error", "device", "note"
    text: str

    def line(self, source: str) -> str:
        return f"{source}: {self.key}: {self.text}"


_SEVERITY_OF = {"missing": "device", "invalid": "error", "unchecked": "note"}


def findings(cfg: Config, running: Config | None = None) -> list[Finding]:
    """Every check `run` makes before it serves; with `running` (a reload), only of the
    wires whose settings differ from it."""
    def changed(section: str, *names: str) -> bool:
        return running is None or any(getattr(getattr(running, section), n) != getattr(getattr(cfg, section), n)
                                      for n in names)

    found: list[Finding] = []
    port = cfg.serial.port
    if not changed("serial", "port"):
        pass
    elif port is None:
        found.append(Finding("serial.port", "error",
                             "not set: set it to the board's serial device (e.g. /dev/ttyUSB0 or "
                             "/dev/serial/by-id/…), or to \"emulated\" for the built-in virtual board"))
    elif port == EMULATED:
        if importlib.util.find_spec("scipy") is None:  # the simulator behind it is an offline tool
            found.append(Finding("serial.port", "error", "the emulated board needs the offline tools: "
                                 "pip install 'adxl-gateway[offline]'"))
        else:
            found.append(Finding("serial.port", "note", "the built-in emulated board: every value is simulated"))
    else:
        found += _link("serial.port", check_serial_port(port))
    if port == EMULATED and running is not None and changed("serial", "emulated_rset_kohm"):
        found.append(Finding("serial.emulated_rset_kohm", "error",
                             "read when the emulated board starts: restart the gateway to apply it"))
    if cfg.service.view and importlib.util.find_spec("rich") is None:
        found.append(Finding("service.view", "error", "the live view needs the offline tools: "
                             "pip install 'adxl-gateway[offline]'"))
    if cfg.estimator.drift_model and changed("estimator", "drift_model"):
        from gateway.drift_model_file import load_drift_model  # numpy: only when a model is set

        try:
            load_drift_model(cfg.estimator.drift_model)
        except InputError as err:
            found.append(Finding("estimator.drift_model", "error", str(err)))
    if cfg.calibration.model and (changed("calibration", "model") or running is not None):
        # read again at every reload even when its name is unchanged: the file may have been
        # rewritten, and a reload applies what it says now
        try:
            load_sample_path_model(cfg.calibration.model)
        except InputError as err:
            found.append(Finding("calibration.model", "error", str(err)))
    if cfg.modbus.tcp_enabled and changed("modbus", "tcp_enabled", "host", "port"):
        found += _modbus_listen(cfg.modbus.host, cfg.modbus.port)
    if cfg.modbus.rtu_enabled and changed("modbus", "rtu_enabled", "rtu_port"):
        found += _link("modbus.rtu_port", check_serial_port(cfg.modbus.rtu_port))
    if cfg.can.enabled and changed("can", "enabled", "interface", "channel"):
        link = check_can_link(cfg.can.interface, cfg.can.channel)
        found += _link("can.interface" if link.wrong_interface else "can.channel", link)
    if cfg.mqtt.enabled:
        found += _mqtt_files(cfg, changed)
    return found


def _mqtt_files(cfg: Config, changed) -> list[Finding]:
    """The files [mqtt] points to. The credentials file is configuration (its format is
    ours): an error, exit 2. The TLS CA file is what the link to the broker needs to be
    set up at all: unusable, exit 3, as a Modbus port that cannot be bound."""
    m = cfg.mqtt
    found: list[Finding] = []
    if m.credentials_file and changed("mqtt", "enabled", "credentials_file"):
        try:
            read_credentials(m.credentials_file, m.credentials_file)
        except ConfigError as err:
            found.append(Finding("mqtt.credentials_file", "error", str(err)))
    if m.tls_ca_file and changed("mqtt", "enabled", "tls_ca_file"):
        problem = tls_ca_problem(m.tls_ca_file)
        if problem:
            found.append(Finding("mqtt.tls_ca_file", "unusable", f"{m.tls_ca_file}: {problem}"))
    return found


def _modbus_listen(host: str, port: int) -> list[Finding]:
    """The Modbus TCP address and port, tried by binding them (what the server will do)."""
    try:
        socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as err:
        return [Finding("modbus.host", "error", f"{host!r} does not resolve ({err})")]
    problem = tcp_listen_check(host, 0)  # the address alone: is it one of this machine's?
    if problem:
        return [Finding("modbus.host", "error", problem)]
    problem = tcp_listen_check(host, port)
    return [Finding("modbus.port", "unusable", problem)] if problem else []


def _link(key: str, check) -> list[Finding]:
    if check.verdict == "ok":
        return [Finding(key, "note", check.detail)] if check.detail else []
    return [Finding(key, _SEVERITY_OF[check.verdict], check.detail)]


def refuse_unrunnable(cfg: Config) -> list[Finding]:
    """At start: ConfigError (exit 2) naming every error, else DeviceError (exit 3) naming
    every unusable port; returns the rest (what run waits for, notes)."""
    found = findings(cfg)
    for severity, error in (("error", ConfigError), ("unusable", DeviceError)):
        lines = [f.line(cfg.source) for f in found if f.severity == severity]
        if lines:
            raise error("\n".join(lines))
    return found


def refuse_reload(running: Config, new: Config) -> None:
    """At a reload: ConfigError naming every finding but a note on a wire the reload
    changes — a reload is applied whole or not at all."""
    lines = [f.line(new.source) for f in findings(new, running) if f.severity != "note"]
    if lines:
        raise ConfigError("\n".join(lines))
