"""The one MQTT packet the Sparkplug node writes to the socket itself: a QoS 0 PUBLISH
(MQTT 3.1.1, section 3.3). drivers/sparkplug_node.py sends its DDATA this way when paho has
nothing queued and the packet fits one TCP segment; everything else goes through paho."""

from __future__ import annotations

#: The largest QoS 0 PUBLISH written straight to the socket (a DDATA is 30–120 bytes): one
#: TCP segment on any link (the IPv6 minimum MTU 1280 less the IPv6 and TCP headers with
#: options), which a non-blocking send takes whole or refuses whole but for a buffer that
#: runs out in the middle of it; a larger packet goes through paho, which resumes writes.
MAX_DIRECT_PACKET = 1280 - 40 - 60


def mqtt_varint(n: int) -> bytes:
    """MQTT's remaining length (and protobuf's varint): 7 bits a byte, low first. The
    one-byte values (most of a DDATA's, and its packet's length) from a table: this runs
    several times per DDATA, cold on a VM, where the loop costs more than the lookup."""
    if n < 0x80:
        return _ONE_BYTE[n]
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


_ONE_BYTE = tuple(bytes((n,)) for n in range(0x80))


def qos0_publish_packet(topic_field: bytes, payload: bytes) -> bytes:
    """An MQTT 3.1.1 PUBLISH at QoS 0, not retained (section 3.3): fixed header 0x30, the
    remaining length, the topic as a length-prefixed string (`topic_field`, made once per
    topic by `topic_field()`), the payload. No packet identifier at QoS 0."""
    return b"\x30" + mqtt_varint(len(topic_field) + len(payload)) + topic_field + payload


def topic_field(topic: str) -> bytes:
    encoded = topic.encode()
    return len(encoded).to_bytes(2, "big") + encoded
