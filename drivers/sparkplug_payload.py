"""Sparkplug B on the wire: the topic namespace, the metrics table, payloads in and out.

`NODE_METRICS` and `DEVICE_METRICS` are the single source: the edge node encodes from
them, the host view decodes with them, and docs/mqtt.md embeds `metrics_markdown()`
(a test keeps them equal). The payload is Eclipse Tahu's `sparkplug_b.proto`
(drivers/sparkplug/, EPL-2.0), compiled once into `sparkplug_b_pb2`.

Conventions, said once:
- Topics: ``spBv1.0/<group>/<NBIRTH|NDATA|NDEATH|NCMD>/<edge node>`` and
  ``spBv1.0/<group>/<DBIRTH|DDATA|DDEATH|DCMD>/<edge node>/<device>``.
- A birth carries every metric with its name and alias; DATA carries aliases only, and
  only the metrics whose value changed since the last DATA (report by exception).
- A number the gateway does not have (NaN, no temperature sensor) is sent with
  ``is_null`` set, never as a made-up value.
- seq counts every NBIRTH/DBIRTH/DDATA of a session modulo 256 (NBIRTH is 0); bdSeq
  counts MQTT sessions modulo 256 and ties an NDEATH (the MQTT will) to its NBIRTH.
"""
from __future__ import annotations

import enum
import functools
import json
import math
import operator
import struct
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .mqtt_packet import mqtt_varint
from .published_values import Command, PublishedValues, StatusBits, StatusExtBits, usable_status
from .sparkplug import sparkplug_b_pb2

NAMESPACE = "spBv1.0"
SEQ_MODULO = 256  # seq and bdSeq are 0..255
Payload = sparkplug_b_pb2.Payload


class DataType(enum.IntEnum):
    """Sparkplug B metric data types (the numbers of Tahu's DataType enum) used here."""

    INT64 = 4
    UINT32 = 7
    UINT64 = 8
    DOUBLE = 10
    BOOLEAN = 11
    STRING = 12


_VALUE_FIELD = {DataType.INT64: "long_value", DataType.UINT32: "int_value", DataType.UINT64: "long_value",
                DataType.DOUBLE: "double_value", DataType.BOOLEAN: "boolean_value",
                DataType.STRING: "string_value"}


@dataclass(frozen=True, slots=True)
class MetricDef:
    name: str
    datatype: DataType
    unit: str
    description: str
    #: The PublishedValues attribute the value is read from (a Double that is not finite
    #: is sent as null); None for the metrics the node fills itself and the commands.
    source: str | None = None


#: Node metrics: in NBIRTH (and bdSeq in NDEATH). "Node Control/Rebirth" is the host's way
#: to ask for the births again (an NCMD with it true).
BDSEQ = "bdSeq"
REBIRTH = "Node Control/Rebirth"
NODE_METRICS: tuple[MetricDef, ...] = (
    MetricDef(BDSEQ, DataType.INT64, "", "MQTT session of this node (0–255); the NDEATH with the same bdSeq ends it."),
    MetricDef(REBIRTH, DataType.BOOLEAN, "",
              "Write true (NCMD): the node publishes NBIRTH and DBIRTH again. Reads false."),
    MetricDef("Properties/version", DataType.STRING, "", "The gateway's software version."),
)

DDATA_COUNT = "mqtt/ddata_count"
MQTT_DROPPED = "mqtt/dropped"
COMMAND_PREFIX = "Commands/"

_MEASURED: tuple[MetricDef, ...] = (
    MetricDef("position_m", DataType.DOUBLE, "m", "Position since the tare (null: no estimate).", "position_m"),
    MetricDef("velocity_mps", DataType.DOUBLE, "m/s", "Velocity.", "velocity_mps"),
    MetricDef("acceleration_mps2", DataType.DOUBLE, "m/s²", "Acceleration along the axis, bias removed.",
              "acceleration_mps2"),
    MetricDef("position_std_m", DataType.DOUBLE, "m", "1σ of the position estimate.", "position_std_m"),
    MetricDef("bias_estimate_mps2", DataType.DOUBLE, "m/s²", "The accelerometer bias the estimator removes.",
              "bias_estimate_mps2"),
    MetricDef("board_temp_c", DataType.DOUBLE, "°C", "Board temperature (null: no sensor or no STATUS yet).",
              "board_temp_c"),
    MetricDef("last_sample_age_ms", DataType.DOUBLE, "ms", "Age of the newest sample (null: none yet).",
              "last_sample_age_ms"),
    MetricDef("usable", DataType.BOOLEAN, "", "VALID set and no bit against it: the numbers may be acted on.",
              "usable"),
    MetricDef("status", DataType.UINT32, "", "The status word (StatusBits), as in Modbus STATUS.", "status"),
    MetricDef("status_ext", DataType.UINT32, "", "The second status word (StatusExtBits), as in Modbus STATUS_EXT.",
              "status_ext"),
)


def _bit_metric(prefix: str, bit: enum.IntFlag, word: str) -> MetricDef:
    # read through _bits(): one dict per status pair, not 23 flag operations per snapshot
    return MetricDef(f"{prefix}/{bit.name}", DataType.BOOLEAN, "", f"Bit {bit.value.bit_length() - 1} of {word}.")


_BITS: tuple[MetricDef, ...] = tuple(_bit_metric("status", b, "status") for b in StatusBits) + tuple(
    _bit_metric("status_ext", b, "status_ext") for b in StatusExtBits)

_COUNTERS: tuple[MetricDef, ...] = (
    MetricDef("sample_counter", DataType.UINT64, "count", "Board samples processed since start.", "sample_counter"),
    MetricDef("lost_samples", DataType.UINT64, "count", "Samples missing on the serial line since start.",
              "lost_samples"),
    MetricDef("crc_errors", DataType.UINT64, "count", "Board frames dropped for a CRC mismatch since start.",
              "crc_errors"),
    MetricDef("board_resets", DataType.UINT64, "count", "Board resets seen since start.", "board_resets"),
    MetricDef("can_send_errors", DataType.UINT64, "count", "CAN frames that could not be sent since start.",
              "can_send_errors"),
    MetricDef(DDATA_COUNT, DataType.UINT64, "count",
              "DDATA messages this node made since start, sent or not: a host that sees it jump has lost "
              "messages (the node's own drops are in mqtt/dropped)."),
    MetricDef(MQTT_DROPPED, DataType.UINT64, "count",
              "DDATA messages this node dropped since start: its queue was full (a broker away for longer "
              "than the backlog holds, or slower than the rate)."),
)

_COMMANDS: tuple[MetricDef, ...] = tuple(
    MetricDef(f"{COMMAND_PREFIX}{c.name}", DataType.BOOLEAN, "",
              f"Write true (DCMD): the command {c.name}, as over Modbus and CAN; refused unless "
              "mqtt.commands_enabled. Reads false.") for c in Command)

#: Device metrics: in DBIRTH, and those that changed in each DDATA.
DEVICE_METRICS: tuple[MetricDef, ...] = _MEASURED + _BITS + _COUNTERS + _COMMANDS

#: Aliases: fixed by the tables' order (node metrics first), the same in every birth.
ALIASES: dict[str, int] = {m.name: i + 1 for i, m in enumerate(NODE_METRICS + DEVICE_METRICS)}
BY_NAME: dict[str, MetricDef] = {m.name: m for m in NODE_METRICS + DEVICE_METRICS}
BY_ALIAS: dict[int, MetricDef] = {ALIASES[m.name]: m for m in NODE_METRICS + DEVICE_METRICS}
#: DCMD metric name → the command it carries.
COMMANDS: dict[str, Command] = {f"{COMMAND_PREFIX}{c.name}": c for c in Command}
_READABLE = tuple(m for m in DEVICE_METRICS if m.source is not None)
# device_row's work, prepared once: it runs rate_hz times a second in the daemon's event
# loop, cold each time, so it reads the snapshot with one C call and loops only over the
# few metrics that need converting
_READABLE_NAMES = tuple(m.name for m in _READABLE)
_DOUBLE_INDEXES = tuple(i for i, m in enumerate(_READABLE) if m.datatype is DataType.DOUBLE)
_WORD_INDEXES = (_READABLE_NAMES.index("status"), _READABLE_NAMES.index("status_ext"))
_USABLE_INDEX = _READABLE_NAMES.index("usable")
# (`usable` read as the status word and made from it in ints: the property is flag operations)
_READ_SOURCES = operator.attrgetter(*("status" if m.source == "usable" else m.source for m in _READABLE))


# ------------------------------------------------------------------ topics --
def node_topic(group: str, kind: str, node: str) -> str:
    return f"{NAMESPACE}/{group}/{kind}/{node}"


def device_topic(group: str, kind: str, node: str, device: str) -> str:
    return f"{NAMESPACE}/{group}/{kind}/{node}/{device}"


def state_topic(host_id: str) -> str:
    """Where a primary host application says whether it is online (Sparkplug 3.0)."""
    return f"{NAMESPACE}/STATE/{host_id}"


@dataclass(frozen=True, slots=True)
class HostState:
    online: bool
    timestamp_ms: int


MAX_STATE_BYTES = 1024  # {"online": true, "timestamp": <ms>}: tens of bytes; more is not that


def encode_state(state: HostState) -> bytes:
    """A primary host's STATE payload (Sparkplug 3.0): JSON, UTF-8."""
    return json.dumps({"online": state.online, "timestamp": state.timestamp_ms}).encode()


def decode_state(data: bytes) -> HostState:
    """A STATE payload (JSON: online, timestamp in UTC ms); ValueError naming what is wrong."""
    if len(data) > MAX_STATE_BYTES:
        raise ValueError(f"STATE payload of {len(data)} bytes (at most {MAX_STATE_BYTES})")
    try:
        state = json.loads(data)
    except (ValueError, RecursionError) as err:  # (UnicodeDecodeError is a ValueError)
        raise ValueError(f"STATE payload is not JSON: {err}") from err
    online = state.get("online") if isinstance(state, dict) else None
    timestamp = state.get("timestamp") if isinstance(state, dict) else None
    if not isinstance(online, bool) or isinstance(timestamp, bool) or not isinstance(timestamp, int) or timestamp < 0:
        raise ValueError('STATE payload is not {"online": true|false, "timestamp": <UTC ms>}')
    return HostState(online, timestamp)


@dataclass(frozen=True, slots=True)
class Topic:
    group: str
    kind: str  # NBIRTH, DDATA, ...
    node: str
    device: str | None = None


def parse_topic(topic: str) -> Topic | None:
    """A Sparkplug B topic's parts; None for anything else (STATE, other namespaces)."""
    parts = topic.split("/")
    if len(parts) not in (4, 5) or parts[0] != NAMESPACE:
        return None
    return Topic(parts[1], parts[2], parts[3], parts[4] if len(parts) == 5 else None)


# --------------------------------------------------------------- payloads --
_STATUS_MASKS = tuple((f"status/{b.name}", int(b)) for b in StatusBits)
_EXT_MASKS = tuple((f"status_ext/{b.name}", int(b)) for b in StatusExtBits)


@functools.lru_cache(maxsize=256)
def _bits(status: int, status_ext: int) -> dict[str, bool]:
    """The status bits as metrics; few distinct words in a run, so made once each
    (the node reads a snapshot rate_hz times a second, in the daemon's event loop)."""
    bits = {name: bool(status & mask) for name, mask in _STATUS_MASKS}
    bits.update((name, bool(status_ext & mask)) for name, mask in _EXT_MASKS)
    return bits


Reading = tuple[Any, ...]


def device_reading(values: PublishedValues) -> Reading:
    """The readable device metrics of one snapshot but the status bits, in table order,
    as one tuple: what the node compares each 1/rate_hz (a tuple equal to the last one is
    one C comparison; the bits follow from the two words). A Double that is not finite
    (NaN: no estimate) is None, sent as null."""
    read = list(_READ_SOURCES(values))
    for i in _DOUBLE_INDEXES:
        x = read[i]
        if x is not None and not math.isfinite(x):
            read[i] = None
    i, j = _WORD_INDEXES
    read[i], read[j] = int(read[i]), int(read[j])
    read[_USABLE_INDEX] = usable_status(read[i])
    return tuple(read)


def row_of(reading: Reading) -> dict[str, Any]:
    """Every readable device metric by name, the status bits included (a birth's row)."""
    row = dict(zip(_READABLE_NAMES, reading, strict=True))
    i, j = _WORD_INDEXES
    row.update(_bits(reading[i], reading[j]))
    return row


def device_row(values: PublishedValues) -> dict[str, Any]:
    """The readable device metrics of one snapshot (commands and the node's counters aside)."""
    return row_of(device_reading(values))


def reading_changes(previous: Reading | None, reading: Reading) -> dict[str, Any]:
    """The metrics whose value differs from `previous` (all of them without one), the
    status bits that flipped included."""
    if previous is None:
        return row_of(reading)
    if previous == reading:
        return {}
    changed = {name: new for name, old, new in zip(_READABLE_NAMES, previous, reading, strict=True) if old != new}
    i, j = _WORD_INDEXES
    if previous[i] != reading[i] or previous[j] != reading[j]:
        old_bits, new_bits = _bits(previous[i], previous[j]), _bits(reading[i], reading[j])
        changed.update((name, bit) for name, bit in new_bits.items() if old_bits[name] != bit)
    return changed


#: name → (alias, datatype number, the Metric's value field): what encoding a metric needs,
#: looked up once per metric (a DDATA is encoded rate_hz times a second)
_ENCODING: dict[str, tuple[int, int, str]] = {
    m.name: (ALIASES[m.name], int(m.datatype), _VALUE_FIELD[m.datatype]) for m in NODE_METRICS + DEVICE_METRICS}


def _add(payload, name: str, value: Any, *, birth: bool, timestamp_ms: int | None = None,
         historical: bool = False) -> None:
    alias, datatype, value_field = _ENCODING[name]
    metric = payload.metrics.add()
    if birth or name == BDSEQ:
        metric.name = name  # births name every metric; NDEATH's bdSeq goes by name
    if birth or name != BDSEQ:
        metric.alias = alias
    if timestamp_ms is not None:
        metric.timestamp = timestamp_ms
    if historical:
        metric.is_historical = True
    metric.datatype = datatype
    if value is None:
        metric.is_null = True
    else:
        setattr(metric, value_field, value)


def node_birth(timestamp_ms: int, seq: int, bd_seq: int, version: str) -> bytes:
    p = Payload(timestamp=timestamp_ms, seq=seq)
    _add(p, BDSEQ, bd_seq, birth=True)
    _add(p, REBIRTH, False, birth=True)
    _add(p, "Properties/version", version, birth=True)
    return p.SerializeToString()


def node_death(bd_seq: int) -> bytes:
    p = Payload()
    _add(p, BDSEQ, bd_seq, birth=False)
    return p.SerializeToString()


def device_birth(timestamp_ms: int, seq: int, row: Mapping[str, Any]) -> bytes:
    p = Payload(timestamp=timestamp_ms, seq=seq)
    for name, value in row.items():
        _add(p, name, value, birth=True)
    for name in COMMANDS:
        _add(p, name, False, birth=True)
    return p.SerializeToString()


def device_data(timestamp_ms: int, seq: int, changed: Mapping[str, Any], *, historical: bool = False) -> bytes:
    """DDATA with the changed metrics; historical: values of a moment ago sent late (kept
    while the broker was away), flagged so that no host takes them as the current ones.

    Written as protobuf bytes here, not through the generated classes: a DDATA is made
    rate_hz times a second in the daemon's event loop, cold each time, and a message
    object with one `add` and three or four attribute sets per metric was most of its
    encoding (docs/decisions/0153). What does not change from one message to the next —
    a metric's alias, datatype and value tag, a current Double's whole prefix, a null or
    a boolean whole — is made once (`_CURRENT`, `_HISTORICAL`); only the values are
    encoded per message. The bytes are those protobuf makes for the same message, field
    for field (tests/mqtt/test_mqtt_payload.py compares them)."""
    stamp = _varint(timestamp_ms)
    parts = [b"\x08", stamp]  # timestamp (field 1)
    append = parts.append
    if historical:  # (rare: the backlog after a reconnect) each metric carries its time and the flag
        metric_stamp = b"\x18" + stamp
        for name, value in changed.items():
            alias_field, datatype_field, encode = _HISTORICAL[name]
            metric = alias_field + metric_stamp + datatype_field + b"\x28\x01" + (
                _NULL if value is None else encode(value))
            append(b"\x12" + _varint(len(metric)) + metric)
    else:
        for name, value in changed.items():
            null_entry, entry = _CURRENT[name]
            append(null_entry if value is None else entry(value))
    append(b"\x18")  # seq (field 3)
    append(_varint(seq))
    return b"".join(parts)


#: Protobuf's base-128 varint of a non-negative int (uint32/uint64 fields) is MQTT's
#: remaining-length encoding
_varint = mqtt_varint
_PACK_DOUBLE = struct.Struct("<d").pack
# Payload.metrics is field 2 (a length-delimited Metric); in a Metric (sparkplug_b.proto):
# alias 2, timestamp 3, datatype 4, is_historical 5, is_null 7; the values int_value 10
# (uint32, varint), long_value 11 (uint64, varint), double_value 13 (fixed64),
# boolean_value 14 (varint), string_value 15 (length-delimited)
_NULL = b"\x38\x01"
_INT_TAGS = {DataType.UINT32: b"\x50", DataType.UINT64: b"\x58"}
_VALUE_ENCODERS: dict[DataType, Callable[[Any], bytes]] = {
    DataType.UINT32: lambda v: _INT_TAGS[DataType.UINT32] + _varint(v),
    DataType.UINT64: lambda v: _INT_TAGS[DataType.UINT64] + _varint(v),
    DataType.DOUBLE: lambda v: b"\x69" + _PACK_DOUBLE(v),
    DataType.BOOLEAN: lambda v: b"\x70\x01" if v else b"\x70\x00",
    DataType.STRING: lambda v: b"\x7a" + _varint(len(b := v.encode())) + b,
}


def _entry(metric: bytes) -> bytes:
    return b"\x12" + _varint(len(metric)) + metric


def _double_prefix(head: bytes) -> bytes:
    """A current Double's Payload.metrics entry but its 8 value bytes (fixed length)."""
    return _entry(head + b"\x69" + bytes(8))[:-8]


def _current_encoder(head: bytes, datatype: DataType) -> Callable[[Any], bytes]:
    """A current DDATA's metric (alias, datatype, value) as a Payload.metrics entry."""
    if datatype is DataType.DOUBLE:  # fixed length: everything but the 8 bytes is made once
        prefix = _double_prefix(head)
        return lambda v: prefix + _PACK_DOUBLE(v)
    if datatype is DataType.BOOLEAN:
        true, false = _entry(head + b"\x70\x01"), _entry(head + b"\x70\x00")
        return lambda v: true if v else false
    if datatype in _INT_TAGS:
        # a varint is 1–10 bytes, so the metric is shorter than 128 bytes and its length one
        # byte: the entry's prefix for each varint length made once, one lookup per value
        tagged = head + _INT_TAGS[datatype]
        prefixes = tuple(b"\x12" + bytes((len(tagged) + k,)) + tagged for k in range(11))
        return lambda v: prefixes[len(value := _varint(v))] + value
    encode = _VALUE_ENCODERS[datatype]
    return lambda v: _entry(head + encode(v))


def _heads(m: MetricDef) -> tuple[bytes, bytes]:
    return b"\x10" + _varint(ALIASES[m.name]), b"\x20" + _varint(int(m.datatype))


#: name → (the entry of a null, the encoder of a value): a current DDATA's metrics
_CURRENT: dict[str, tuple[bytes, Callable[[Any], bytes]]] = {
    m.name: (_entry(b"".join(_heads(m)) + _NULL), _current_encoder(b"".join(_heads(m)), m.datatype))
    for m in DEVICE_METRICS}
#: name → (the alias field, the datatype field, the value's encoder): a historical one's
_HISTORICAL: dict[str, tuple[bytes, bytes, Callable[[Any], bytes]]] = {
    m.name: (*_heads(m), _VALUE_ENCODERS[m.datatype]) for m in DEVICE_METRICS}


#: per slot of a Reading, in order: its null entry, and for a Double the entry's prefix
#: (all but the 8 value bytes) or else its encoder — what changed_device_data needs per slot
_SLOT_NULLS = tuple(_CURRENT[name][0] for name in _READABLE_NAMES)
_SLOT_DOUBLE_PREFIXES = tuple(_double_prefix(b"".join(_heads(m)))
                              if m.datatype is DataType.DOUBLE else None for m in _READABLE)
_SLOT_ENCODERS = tuple(_CURRENT[m.name][1] for m in _READABLE)
_SLOTS = tuple(zip(_SLOT_NULLS, _SLOT_DOUBLE_PREFIXES, _SLOT_ENCODERS, strict=True))


def changed_device_data(timestamp_ms: int, seq: int, previous: Reading, reading: Reading, ddata_count: int,
                        dropped: int | None = None) -> bytes:
    """The current DDATA from `previous` to `reading` (not equal): the metrics that changed,
    the status bits that flipped, then the node's own `mqtt/ddata_count` and, when given,
    `mqtt/dropped` — the bytes `device_data` makes of `reading_changes(previous, reading)`
    with those two added (tests/mqtt/test_mqtt_payload.py compares them), in one pass over
    the reading's slots: the edge node's due tick, rate_hz times a second in the daemon's
    event loop and cold each time, then builds no dict of changes, looks no metric up by
    name and packs a Double with one C call (docs/decisions/0154)."""
    parts = [b"\x08", _varint(timestamp_ms)]  # timestamp (field 1)
    append = parts.append
    for (null_entry, double_prefix, encode), old, new in zip(_SLOTS, previous, reading, strict=True):
        if old != new:
            if new is None:
                append(null_entry)
            elif double_prefix is not None:
                append(double_prefix + _PACK_DOUBLE(new))
            else:
                append(encode(new))
    i, j = _WORD_INDEXES
    if previous[i] != reading[i] or previous[j] != reading[j]:
        old_bits = _bits(previous[i], previous[j])
        for name, bit in _bits(reading[i], reading[j]).items():
            if old_bits[name] != bit:
                append(_CURRENT[name][1](bit))
    append(_DDATA_COUNT_ENTRY(ddata_count))
    if dropped is not None:
        append(_DROPPED_ENTRY(dropped))
    append(b"\x18")  # seq (field 3)
    append(_varint(seq))
    return b"".join(parts)


_DDATA_COUNT_ENTRY = _CURRENT[DDATA_COUNT][1]
_DROPPED_ENTRY = _CURRENT[MQTT_DROPPED][1]


@dataclass(frozen=True, slots=True)
class DecodedMetric:
    name: str
    value: Any  # None when null
    historical: bool


def decode(data: bytes) -> tuple[Payload, list[DecodedMetric]]:
    """A payload and its metrics by name (aliases resolved through the table). Raises
    ValueError for bytes that are no Sparkplug B payload; unknown metrics are skipped."""
    try:
        payload = Payload.FromString(data)
    except Exception as err:  # protobuf's DecodeError, and whatever a hostile payload raises
        raise ValueError(f"not a Sparkplug B payload: {err}") from err
    metrics = []
    for m in payload.metrics:
        definition = BY_NAME.get(m.name) if m.name else BY_ALIAS.get(m.alias)
        if definition is None:
            continue
        value = None if m.is_null else getattr(m, _VALUE_FIELD[definition.datatype])
        metrics.append(DecodedMetric(definition.name, value, m.is_historical))
    return payload, metrics


# ------------------------------------------------------------------- docs --
def metrics_markdown() -> str:
    """The metrics table of docs/mqtt.md."""
    lines = ["| metric | alias | message | type | unit | meaning |", "| --- | --- | --- | --- | --- | --- |"]

    special = {BDSEQ: "NBIRTH, NDEATH", REBIRTH: "NBIRTH, NCMD", **{name: "DBIRTH, DCMD" for name in COMMANDS}}

    def rows(defs: Iterable[MetricDef], where: str) -> None:
        for m in defs:
            lines.append(f"| `{m.name}` | {ALIASES[m.name]} | {special.get(m.name, where)} | "
                         f"{m.datatype.name.title()} | {m.unit} | {m.description} |")

    rows(NODE_METRICS, "NBIRTH")
    rows(DEVICE_METRICS, "DBIRTH, DDATA")
    return "\n".join(lines) + "\n"
