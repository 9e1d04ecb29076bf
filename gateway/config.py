"""The gateway's TOML configuration: one schema table, validated at start.

The schema below is the single source for defaults, validation and the commented
default file that `adxlgw config --default` prints. An unknown key or a bad value is
one ``ConfigError`` that names the file and the key (exit code 2). A key whose default
is None has none on purpose (the board's port: a gateway must not guess its wire);
`adxlgw run` refuses to start until it is set (gateway/daemon/preflight.py).
"""
from __future__ import annotations

import difflib
import ipaddress
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.modbus_map import string32_complaint
from gateway.errors import ConfigError


@dataclass(frozen=True)
class Key:
    section: str
    name: str
    default: Any
    kind: type | tuple  # bool, int, float, str, list
    doc: str
    check: Callable[[Any], str | None] | None = None  # returns a complaint or None
    example: Any = None  # shown, commented out, in the default file when default is None

    @property
    def dotted(self) -> str:
        return f"{self.section}.{self.name}"


def _range(lo=None, hi=None, *, lo_open=False):
    def check(v):
        if isinstance(v, float) and not math.isfinite(v):
            return "must be finite"
        if lo is not None and (v <= lo if lo_open else v < lo):
            return f"must be {'>' if lo_open else '≥'} {lo}"
        if hi is not None and v > hi:
            return f"must be ≤ {hi}"
        return None
    return check


def _one_of(*choices):
    def check(v):
        return None if v in choices else f"must be one of {', '.join(map(repr, choices))}"
    return check


def _addresses(v):
    for item in v:
        if not isinstance(item, str):
            return f"entries must be strings, got {item!r}"
        try:
            ipaddress.ip_network(item, strict=False)
        except ValueError:
            return f"{item!r} is not an IP address or network"
    return None


def travel_problem(v) -> str | None:
    """What is wrong with an axis's travel [lowest, highest] (m), or None: the config's
    estimator.travel_m and `adxlgw estimate --travel-m` check it here."""
    if len(v) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return "must be two numbers, [lowest, highest]"
    lo, hi = (float(x) for x in v)
    if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
        return "must be finite, lowest < highest"
    if max(abs(lo), abs(hi)) > MAX_TRAVEL_M:
        return f"must lie within ±{MAX_TRAVEL_M:g} m"
    return None


#: no linear axis this gateway serves is longer: the state file's own limit (state_store)
MAX_TRAVEL_M = 1.0e4


def _nonempty(v):
    return None if v.strip() else "must not be empty"


def sparkplug_id_problem(v):
    # Sparkplug B: a topic level, so none of MQTT's separators or wildcards
    if not v.strip():
        return "must not be empty"
    if any(c in v for c in "/+#") or not v.isprintable():
        return "must be printable and hold none of / + #"
    return None


def _sparkplug_id_or_empty(v):
    return None if v == "" else sparkplug_id_problem(v)


SCHEMA: tuple[Key, ...] = (
    # --- the board ---------------------------------------------------------
    Key("serial", "port", None, str,
        "Board serial port: a device path (/dev/ttyUSB0, /dev/serial/by-id/…), a pyserial URL "
        "(socket://host:port, loop://), or \"emulated\" for the built-in virtual board (simulated "
        "values, flagged on every wire). No default: adxlgw run refuses to start until it is set.",
        _nonempty, example="/dev/ttyUSB0"),
    Key("serial", "emulated_rset_kohm", 250.0, float,
        "RSET of the built-in emulated board's ADXL202 (port = \"emulated\" only), kΩ: it sets the "
        "sensor period, T2 = RSET / 125 MΩ (data sheet: T2 0.5–10 ms). 250: the board's 2 ms, 500 "
        "samples/s; 1250: 10 ms, 100 samples/s. Read when the emulated board starts.",
        _range(62.5, 1250)),
    Key("serial", "baudrate", 115200, int, "Line speed of the board (8N1).", _range(1200, 4_000_000)),
    Key("serial", "reconnect_min_s", 0.2, float, "First wait before reopening a lost port, s.", _range(0.01, 60)),
    Key("serial", "reconnect_max_s", 5.0, float, "Longest wait between reopen attempts, s.", _range(0.01, 600)),
    Key("serial", "batch_frames", 5, int,
        "The kernel wakes the gateway once this many SAMPLE frames' worth of bytes (15 each) have "
        "arrived (termios VMIN; a device or pty, not a pyserial URL). Whatever reads the values — a "
        "Modbus read, a CAN cycle, a command — first takes the bytes that came meanwhile, so no wire "
        "shows older numbers; fewer wakeups cost less CPU (docs/daemon.md). 1: woken at every arrival "
        "(also what can.min_interval_ms ≥ 0 implies: frames per sample need a wakeup per sample).",
        _range(1, 17)),
    Key("serial", "stale_after_ms", 100, int,
        "No sample for this long: the values are stale (status bit STALE).", _range(5, 60_000)),
    Key("serial", "lost_after_ms", 2000, int,
        "No byte for this long: the board is lost (status bit BOARD_LOST).", _range(50, 600_000)),
    # --- calibration -------------------------------------------------------
    Key("calibration", "axis", "x", str, "Which sensor axis lies along the motion.", _one_of("x", "y")),
    Key("calibration", "zero_g_duty_x", 0.5, float, "X axis duty cycle at 0 g (D0).", _range(0.0, 1.0, lo_open=True)),
    Key("calibration", "sensitivity_x", 0.125, float, "X axis duty cycle per g (S).", _range(0.0, 1.0, lo_open=True)),
    Key("calibration", "zero_g_duty_y", 0.5, float, "Y axis duty cycle at 0 g (D0).", _range(0.0, 1.0, lo_open=True)),
    Key("calibration", "sensitivity_y", 0.125, float, "Y axis duty cycle per g (S).", _range(0.0, 1.0, lo_open=True)),
    Key("calibration", "model", "", str,
        "Extended sensor model from 'adxlgw diagnose --model-out' (JSON): its scale, temperature and "
        "motion-offset terms correct every sample before the estimator, its filter terms add to the "
        "estimator's sensor lag; a tilt or cross-talk term is refused (not causal: docs/diagnosis.md). "
        "Empty: none."),
    # --- Modbus ------------------------------------------------------------
    Key("modbus", "tcp_enabled", True, bool, "Serve Modbus TCP."),
    Key("modbus", "host", "127.0.0.1", str, "Address to listen on (0.0.0.0 for every interface).", _nonempty),
    Key("modbus", "port", 5020, int, "TCP port (502 is the standard one and needs privileges).", _range(0, 65535)),
    Key("modbus", "unit_id", 1, int, "Modbus unit (slave) id answered.", _range(0, 247)),
    Key("modbus", "word_order", "ABCD", str,
        "Word order of 32-bit values: ABCD (high word first) or CDAB (low word first).", _one_of("ABCD", "CDAB")),
    Key("modbus", "writes_enabled", False, bool, "Accept commands in the holding registers (tare, re-estimate bias)."),
    Key("modbus", "write_allow", ["127.0.0.1"], list,
        "Client addresses or networks allowed to write when writes are enabled.", _addresses),
    Key("modbus", "rtu_enabled", False, bool, "Also serve Modbus RTU on a serial port (RS-485 to a PLC)."),
    Key("modbus", "rtu_port", "/dev/ttyUSB1", str, "Serial port of the RTU server.", _nonempty),
    Key("modbus", "rtu_baudrate", 19200, int, "RTU line speed.", _range(1200, 4_000_000)),
    Key("modbus", "rtu_parity", "E", str, "RTU parity: N, E or O (Modbus default: E).", _one_of("N", "E", "O")),
    Key("modbus", "rtu_writes_enabled", False, bool, "Accept commands over RTU (it has no client address)."),
    Key("modbus", "max_connections", 64, int,
        "Modbus TCP connections served at once (keep it well below the open-file limit). At the "
        "limit a newcomer gets in by closing the connection that has done least (none of its "
        "requests complete, else idle longest); a client in write_allow or priority_clients is "
        "never closed for anyone else (a newcomer finding only those is refused).", _range(1, 10_000)),
    Key("modbus", "priority_clients", [], list,
        "Addresses or networks that always get a connection, besides those in write_allow "
        "(e.g. the PLC when writes are disabled).", _addresses),
    Key("modbus", "idle_timeout_s", 60.0, float,
        "Close a TCP connection that sent no complete request for this long, s (0: never).", _range(0, 86_400)),
    Key("modbus", "peer_log_interval_s", 10.0, float,
        "Log what a client does wrong (bad frames, refused writes or connections) at most once "
        "per client and interval, with a count, s.", _range(0.1, 3600)),
    Key("modbus", "device_name", "", str,
        "Name of this gateway on Modbus (device identification object 6, registers DEVICE_NAME): "
        "printable ASCII, at most 32 characters.", string32_complaint),
    # --- CAN ---------------------------------------------------------------
    Key("can", "enabled", True, bool, "Publish on CAN."),
    Key("can", "interface", "socketcan", str,
        "python-can interface: socketcan in production (the channel must exist: adxlgw config --check "
        "says so), virtual for tests and the demo.", _nonempty),
    Key("can", "channel", "can0", str, "CAN channel (can0, vcan0, or a virtual bus name).", _nonempty),
    Key("can", "bitrate", 500000, int, "Bit rate where the interface sets it (not socketcan).",
        _range(10_000, 1_000_000)),
    Key("can", "period_ms", 10, int, "Cycle time of the position/velocity/status frames (ms).", _range(1, 10_000)),
    Key("can", "sync_to_updates", True, bool,
        "Send each cycle's frames with the first new values (one per batch of board samples) from "
        "a quarter period before the cycle is due, so they carry those samples at once; none within "
        "half a period after: send anyway. Still one frame pair per period_ms on average. false: "
        "exactly on the timer."),
    Key("can", "min_interval_ms", -1, int,
        "Also send at once whenever new values arrive, at most this often (ms): more frames than one "
        "per period (0: one per sample, ~500/s per frame). -1: off.", _range(-1, 10_000)),
    Key("can", "commands_enabled", False, bool, "Accept the tare command frame."),
    Key("can", "base_id", 0x120, int,
        "11-bit identifier of the position frame; velocity is base_id + 1, the command base_id + 0x10, its "
        "acknowledgement base_id + 0x11 (two gateways on one bus: base IDs at least 0x12 apart). "
        "`adxlgw dbc --config FILE` writes the DBC for these identifiers.", _range(0, 0x7FF - 0x11)),
    # --- MQTT: a Sparkplug B edge node (docs/mqtt.md) ------------------------
    Key("mqtt", "enabled", False, bool,
        "Publish as a Sparkplug B edge node to an MQTT broker (birth, data by exception, death)."),
    Key("mqtt", "host", "127.0.0.1", str, "The broker's address.", _nonempty),
    Key("mqtt", "port", 1883, int, "The broker's port (1883 plain, 8883 with TLS by convention).", _range(1, 65535)),
    Key("mqtt", "group_id", "adxl-gateway", str,
        "Sparkplug group: the plant's line or cell. Topic spBv1.0/<group_id>/<type>/<edge_node_id>[/<device_id>].",
        sparkplug_id_problem),
    Key("mqtt", "edge_node_id", "", str,
        "Sparkplug edge node: this gateway, unique in its group. Empty: the host's name.", _sparkplug_id_or_empty),
    Key("mqtt", "device_id", "axis", str, "Sparkplug device: the axis this gateway measures.", sparkplug_id_problem),
    Key("mqtt", "qos", 0, int,
        "MQTT QoS of births and data: 0 as Sparkplug 3.0 says (a broker restart loses what was in flight), "
        "1 to have the broker acknowledge each message (the death is always QoS 1).", _one_of(0, 1)),
    Key("mqtt", "rate_hz", 20.0, float,
        "Data by exception at most this often: a DDATA with the metrics that changed since the last one.",
        _range(0.1, 100)),
    Key("mqtt", "keepalive_s", 10, int,
        "MQTT keep-alive: a broker that hears nothing for 1.5 × this publishes the node's death.", _range(2, 3600)),
    Key("mqtt", "credentials_file", "", str,
        "A file whose first line is username:password (keep it readable by the gateway only). Empty: none."),
    Key("mqtt", "tls_ca_file", "", str,
        "Connect with TLS, trusting the broker certificates this CA file signs. Empty: plain TCP."),
    Key("mqtt", "primary_host_id", "", str,
        "Sparkplug 3.0 primary host application (the SCADA or historian that must get the data): be born "
        "only once its STATE topic spBv1.0/STATE/<id> says online, keep the data meanwhile (60 s), end the "
        "session when it says offline. Empty: none, born at each connection.", _sparkplug_id_or_empty),
    Key("mqtt", "commands_enabled", False, bool,
        "Accept commands as DCMD (tare, the machine's standstill hint, bias re-estimation); else refused and "
        "counted, as over Modbus and CAN."),
    # --- estimator ---------------------------------------------------------
    Key("estimator", "start_at_rest", True, bool,
        "true (default): the axis stands when the gateway is first started (commissioned at a homed, "
        "resting axis), so the first quiet window is taken as a rest. Believed only on a first start (no "
        "state file) or after an orderly stop at a trusted standstill: after a crash, kill -9, watchdog "
        "abort or a board reset the axis may be mid-move, and the position is POSITION_UNTRUSTED until a "
        "stop is seen on evidence (the machine's rest hint, or a quiet stretch longer than any cruise "
        "within travel_m). false: never "
        "believed (a gateway that may be started mid-move) (docs/decisions/0001-start-at-rest.md)."),
    Key("estimator", "hint_timeout_ms", 1000, int,
        "How long the machine's standstill hint (Modbus CMD_HINT_*, CAN command codes 3-5) stays in "
        "force after it was written; a PLC writes it every cycle while it holds.", _range(10, 600_000)),
    Key("estimator", "travel_m", [-10.0, 10.0], list,
        "The axis's travel, [lowest, highest] published position in m (from the tare point). A saved "
        "position outside it is refused at start (the state file is then moved aside), a restored "
        "position is never less uncertain than the travel allows, and no POSITION_STD is more than the "
        "distance to the farther end of the travel; with the velocity lost, a quiet stretch is a stop only "
        "once it outlasts a cruise at the estimator's speed floor (0.1 m/s) across the travel (10 s per "
        "metre). Default: 10 m either way, 30 times the "
        "paper's 0.3 m stroke and 12 times the robot's 0.8 m move; set your machine's.", travel_problem),
    Key("estimator", "still_while_down", False, bool,
        "true: nothing moves the axis while the gateway is down (it is locked, or the gateway's stop stops "
        "the machine), so a position saved by an orderly stop is restored as exact. false (safe): the "
        "axis may have moved meanwhile; the restored position's POSITION_STD grows with the time it was "
        "not watched, at the machine's top speed, up to the travel (docs/daemon.md, Faults, scored)."),
    Key("estimator", "drift_model", "", str,
        "Zero-drift model of this sensor from 'adxlgw fit-drift --model-out' (JSON); empty: the "
        "sensor model's defaults."),
    # --- state and service -------------------------------------------------
    Key("state", "path", "/var/lib/adxl-gateway/state.json", str,
        "Where calibration and the tare offset survive a restart (written atomically).", _nonempty),
    Key("service", "log_level", "info", str, "debug, info, warning or error.",
        _one_of("debug", "info", "warning", "error")),
    Key("service", "view", False, bool, "Draw a live terminal view of distance, velocity and status."),
)

SECTIONS = tuple(dict.fromkeys(k.section for k in SCHEMA))


class Config:
    """Validated settings; read as cfg.section.key (e.g. cfg.modbus.port)."""

    def __init__(self, values: dict[str, dict[str, Any]], source: str):
        self.source = source
        self._values = values
        for section, keys in values.items():
            setattr(self, section, _Section(section, keys))

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {s: dict(k) for s, k in self._values.items()}

    def replace(self, overrides: dict[str, Any]) -> Config:
        """A copy with dotted-key overrides (from the command line), validated like the file."""
        # keys without a default that are still unset stay unset (validate fills them in)
        data = {s: {k: v for k, v in keys.items() if v is not None} for s, keys in self._values.items()}
        for dotted, value in overrides.items():
            section, name = dotted.split(".", 1)
            data[section][name] = value
        return validate(data, self.source + " (with command-line overrides)")


class _Section:
    def __init__(self, name: str, keys: dict[str, Any]):
        self._name = name
        self.__dict__.update(keys)

    def __repr__(self) -> str:
        items = ", ".join(f"{k}={v!r}" for k, v in self.__dict__.items() if not k.startswith("_"))
        return f"[{self._name}] {items}"


def _type_ok(key: Key, value: Any) -> tuple[bool, Any]:
    if key.kind is bool:
        return isinstance(value, bool), value
    if key.kind is int:
        return isinstance(value, int) and not isinstance(value, bool), value
    if key.kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False, value
        return True, float(value)
    if key.kind is list:
        return isinstance(value, list), value
    return isinstance(value, key.kind), value


_KIND_NAMES = {bool: "true or false", int: "a whole number", float: "a number", str: "a string", list: "a list"}


def validate(data: dict[str, Any], source: str) -> Config:
    """The settings in `data`, or one ConfigError listing every problem, one line each."""
    by_section = {s: {k.name: k for k in SCHEMA if k.section == s} for s in SECTIONS}
    values = {s: {k.name: k.default for k in SCHEMA if k.section == s} for s in SECTIONS}
    problems: list[str] = []
    for section, table in data.items():
        if section not in by_section:
            problems.append(f"unknown section [{section}] (known: {', '.join(SECTIONS)})")
            continue
        if not isinstance(table, dict):
            problems.append(f"[{section}] must be a table")
            continue
        for name, value in table.items():
            key = by_section[section].get(name)
            if key is None:
                near = difflib.get_close_matches(name, by_section[section], n=1)
                problems.append(f"unknown key {section}.{name} " + (
                    f"(did you mean {section}.{near[0]}?)" if near else
                    f"(known in [{section}]: {', '.join(by_section[section])})"))
                continue
            ok, value = _type_ok(key, value)
            if not ok:
                problems.append(f"{key.dotted} = {value!r} must be {_KIND_NAMES[key.kind]}")
                continue
            complaint = key.check(value) if key.check else None
            if complaint:
                problems.append(f"{key.dotted} = {value!r} {complaint}")
                continue
            values[section][name] = value
    if values["can"]["min_interval_ms"] > values["can"]["period_ms"]:
        problems.append("can.min_interval_ms must not exceed can.period_ms")
    if values["serial"]["reconnect_min_s"] > values["serial"]["reconnect_max_s"]:
        problems.append("serial.reconnect_min_s must not exceed serial.reconnect_max_s")
    if values["serial"]["stale_after_ms"] > values["serial"]["lost_after_ms"]:
        # a lost board whose values are not yet stale would be published as fresh
        problems.append("serial.stale_after_ms must not exceed serial.lost_after_ms")
    if not (values["modbus"]["tcp_enabled"] or values["modbus"]["rtu_enabled"] or values["can"]["enabled"]
            or values["mqtt"]["enabled"]):
        problems.append("no output enabled: set modbus.tcp_enabled, modbus.rtu_enabled, can.enabled or mqtt.enabled")
    if problems:
        raise ConfigError("\n".join(f"{source}: {p}" for p in problems))
    return Config(values, source)


MAX_CONFIG_BYTES = 1 << 20  # a real config is a few kB; anything this big is not one


def read_bounded(path: str, max_bytes: int, where: str, kind: str) -> bytes:
    """The bytes of a small file an operator points to (a config, a credentials file),
    read no further than `max_bytes`: ConfigError starting with `where` when it cannot be
    read or is larger — a wrong path (a log, a device) must not be read whole."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as err:
        raise ConfigError(f"{where}: cannot read: {err.strerror or err}") from err
    if len(raw) > max_bytes:
        raise ConfigError(f"{where}: larger than {max_bytes} bytes; not a {kind}")
    return raw


def load_config(path: str | Path | None) -> Config:
    if path is None:
        return validate({}, "<defaults>")
    path = str(path)
    raw = read_bounded(path, MAX_CONFIG_BYTES, path, "config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not UTF-8: byte 0x{raw[err.start]:02x} at offset {err.start}") from err
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err
    except RecursionError as err:  # tomllib parses nested arrays and tables recursively
        raise ConfigError(f"{path}: not a config: arrays or tables nested too deeply") from err
    return validate(data, path)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def default_config_text() -> str:
    lines = [
        "# adxl-gateway configuration (TOML). Every key is shown with its default.",
        "# Unknown keys are errors. Command-line options --serial, --modbus-host, --modbus-port,",
        "# --can-interface and --can-channel override the file.",
    ]
    for section in SECTIONS:
        lines += ["", f"[{section}]"]
        for key in (k for k in SCHEMA if k.section == section):
            lines.append(f"# {key.doc}")
            if key.default is None:  # no default: shown as an example to uncomment
                lines.append(f"# {key.name} = {_toml_value(key.example)}")
            else:
                lines.append(f"{key.name} = {_toml_value(key.default)}")
    return "\n".join(lines) + "\n"
