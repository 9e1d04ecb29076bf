"""Sparkplug B payloads and the host view's state machine, without a broker: the
generated code matches the vendored .proto, the docs embed the metrics table, hostile
bytes never crash the decoder, a stale NDEATH does not kill a reborn node, and a gap in
the node's DDATA count is counted as lost."""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import sparkplug_payload as spb
from drivers.published_values import PublishedValues, StatusBits
from drivers.sparkplug_host import FleetView

ROOT = Path(__file__).resolve().parents[2]
TOPIC = "spBv1.0/g/{kind}/n"
DEVICE = "spBv1.0/g/{kind}/n/axis"


def test_the_generated_module_is_made_from_the_vendored_proto():
    proto = (ROOT / "drivers/sparkplug/sparkplug_b.proto").read_bytes()
    header = (ROOT / "drivers/sparkplug/sparkplug_b_pb2.py").read_text().splitlines()[:3]
    assert f"# proto-sha256: {hashlib.sha256(proto).hexdigest()}" in header, \
        "the .proto changed: run scripts/generate-sparkplug.sh"
    assert (ROOT / "drivers/sparkplug/LICENSE").read_text().startswith("Eclipse Public License - v 2.0")


def test_docs_embed_the_metrics_table_verbatim():
    assert spb.metrics_markdown() in (ROOT / "docs/mqtt.md").read_text(encoding="utf-8"), \
        "docs/mqtt.md is out of date: paste spb.metrics_markdown() into it"


def test_every_metric_has_one_alias_and_a_unit_in_its_name_or_none():
    aliases = list(spb.ALIASES.values())
    assert len(aliases) == len(set(aliases)) == len(spb.NODE_METRICS) + len(spb.DEVICE_METRICS)
    for m in spb.DEVICE_METRICS:
        if m.unit in ("m", "m/s", "m/s²", "°C", "ms"):
            assert m.name.endswith(("_m", "_mps", "_mps2", "_c", "_ms")), m.name


def test_a_number_the_gateway_does_not_have_is_null_not_a_value():
    row = spb.device_row(PublishedValues())  # nothing measured yet
    assert row["position_m"] is None and row["board_temp_c"] is None
    _, metrics = spb.decode(spb.device_birth(1, 1, row))
    by_name = {m.name: m.value for m in metrics}
    assert by_name["position_m"] is None and by_name["status/BOARD_LOST"] is True
    assert by_name["status/VALID"] is False and by_name["usable"] is False


def test_data_by_exception_sends_only_what_changed():
    a = spb.device_reading(PublishedValues(position_m=0.1, status=StatusBits.VALID))
    b = spb.device_reading(PublishedValues(position_m=0.2, status=StatusBits.VALID))
    assert spb.reading_changes(a, b) == {"position_m": 0.2}
    assert spb.reading_changes(a, a) == {}
    nan = spb.device_reading(PublishedValues())  # nothing estimated: NaN is null, and null equals null
    assert spb.reading_changes(nan, spb.device_reading(PublishedValues())) == {}
    assert spb.reading_changes(None, a) == spb.device_row(PublishedValues(position_m=0.1, status=StatusBits.VALID))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_the_decoder_never_raises_anything_but_value_error(data):
    try:
        payload, metrics = spb.decode(data)
    except ValueError:
        return
    for m in metrics:
        assert m.name in spb.BY_NAME


def _birth(view: FleetView, bd_seq: int, now: float) -> None:
    view.handle(TOPIC.format(kind="NBIRTH"), spb.node_birth(1, 0, bd_seq, "x"), now)
    view.handle(DEVICE.format(kind="DBIRTH"), spb.device_birth(1, 1, {**spb.device_row(PublishedValues()),
                                                                     spb.DDATA_COUNT: 0}), now)


def test_a_stale_ndeath_does_not_kill_the_reborn_node():
    view = FleetView()
    _birth(view, bd_seq=4, now=1.0)
    _birth(view, bd_seq=5, now=2.0)  # reconnected before the broker published the old will
    view.handle(TOPIC.format(kind="NDEATH"), spb.node_death(4), 3.0)
    assert view.nodes[("g", "n")].online
    view.handle(TOPIC.format(kind="NDEATH"), spb.node_death(5), 4.0)
    assert not view.nodes[("g", "n")].online


def test_a_gap_in_the_ddata_count_is_lost_and_a_seq_skip_is_counted():
    view = FleetView()
    _birth(view, bd_seq=0, now=1.0)
    view.handle(DEVICE.format(kind="DDATA"), spb.device_data(2, 2, {spb.DDATA_COUNT: 1, "position_m": 0.5}), 2.0)
    view.handle(DEVICE.format(kind="DDATA"), spb.device_data(3, 4, {spb.DDATA_COUNT: 4}), 3.0)
    row = view.rows()[0]
    assert row.lost == 2 and row.seq_gaps == 1 and math.isclose(row.position_m, 0.5)
    # historical data (sent late) are counted but never shown as the current values
    view.handle(DEVICE.format(kind="DDATA"),
                spb.device_data(4, 5, {spb.DDATA_COUNT: 5, "position_m": 9.0}, historical=True), 4.0)
    assert view.rows()[0].position_m == 0.5 and view.rows()[0].lost == 2


def test_a_status_bit_that_changes_is_sent_and_unchanged_bits_are_not():
    a = spb.device_reading(PublishedValues(position_m=0.1, status=StatusBits.VALID))
    b = spb.device_reading(PublishedValues(position_m=0.1, status=StatusBits.VALID | StatusBits.STANDSTILL))
    assert spb.reading_changes(a, b) == {"status": int(StatusBits.VALID | StatusBits.STANDSTILL),
                                         "status/STANDSTILL": True}


_VALUES_BY_TYPE = {
    spb.DataType.DOUBLE: st.one_of(st.none(), st.floats(allow_nan=False)),
    spb.DataType.UINT32: st.one_of(st.none(), st.integers(0, 2**32 - 1)),
    spb.DataType.UINT64: st.one_of(st.none(), st.integers(0, 2**64 - 1)),
    spb.DataType.BOOLEAN: st.one_of(st.none(), st.booleans()),
}
_DDATA_METRICS = list(spb.DEVICE_METRICS)  # (a metric of a type not above: a KeyError, the test fails)


def _protobuf_ddata(timestamp_ms, seq, changed, historical):
    """The oracle: the same DDATA made with the classes generated from the .proto."""
    payload = spb.Payload(timestamp=timestamp_ms, seq=seq)
    for name, value in changed.items():
        m = spb.BY_NAME[name]
        metric = payload.metrics.add(alias=spb.ALIASES[name], datatype=int(m.datatype))
        if historical:
            metric.timestamp = timestamp_ms
            metric.is_historical = True
        if value is None:
            metric.is_null = True
        else:
            setattr(metric, {spb.DataType.DOUBLE: "double_value", spb.DataType.UINT32: "int_value",
                             spb.DataType.UINT64: "long_value", spb.DataType.BOOLEAN: "boolean_value"}[m.datatype],
                    value)
    return payload.SerializeToString()


@settings(max_examples=300, deadline=None)
@given(st.data(), st.integers(0, 2**63), st.integers(0, 255), st.booleans())
def test_a_ddata_is_the_bytes_protobuf_makes_for_it(data, timestamp_ms, seq, historical):
    chosen = data.draw(st.lists(st.sampled_from(_DDATA_METRICS), unique=True, max_size=len(_DDATA_METRICS)))
    changed = {m.name: data.draw(_VALUES_BY_TYPE[m.datatype]) for m in chosen}
    assert spb.device_data(timestamp_ms, seq, changed, historical=historical) == \
        _protobuf_ddata(timestamp_ms, seq, changed, historical)


_READABLE = [m for m in spb.DEVICE_METRICS if m.source is not None]  # a Reading's slots, in order


def _reading_values(data, previous=None):
    values = []
    for k, m in enumerate(_READABLE):
        if previous is not None and data.draw(st.booleans()):
            values.append(previous[k])  # this one unchanged
        elif m.name in ("status", "status_ext"):  # the words are ints; their bits become metrics
            values.append(data.draw(st.integers(0, 2**16 - 1)))
        elif m.datatype is spb.DataType.BOOLEAN:
            values.append(data.draw(st.booleans()))
        else:
            values.append(data.draw(_VALUES_BY_TYPE[m.datatype]))
    return tuple(values)


@settings(max_examples=300, deadline=None)
@given(st.data(), st.integers(0, 2**63), st.integers(0, 255), st.integers(0, 2**64 - 1),
       st.one_of(st.none(), st.integers(0, 2**64 - 1)))
def test_a_ddata_of_two_readings_is_the_ddata_of_their_changes(data, timestamp_ms, seq, count, dropped):
    # the node's one-pass DDATA against the change set encoded by device_data (itself
    # checked against protobuf above): the same bytes
    previous = _reading_values(data)
    reading = _reading_values(data, previous)
    if reading == previous:
        return
    changed = spb.reading_changes(previous, reading)
    changed[spb.DDATA_COUNT] = count
    if dropped is not None:
        changed[spb.MQTT_DROPPED] = dropped
    assert spb.changed_device_data(timestamp_ms, seq, previous, reading, count, dropped) == \
        spb.device_data(timestamp_ms, seq, changed)
