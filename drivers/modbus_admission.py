"""Which Modbus TCP connections the server keeps: a limit, priority clients, idle time.

Pure decisions (no sockets), so they are tested on their own. The server asks
`admit()` for each new connection and `idle()` on a timer.

Policy, chosen so the PLC is never locked out and the process never runs out of file
descriptors (with an open-file limit of 1 024, 1 100 idle connections used to stop
every accept):
- below `max_connections`: everyone gets in;
- at the limit, a priority client (an address in write_allow or priority_clients) gets
  in and the connection idle longest is closed for it — a non-priority one if there is
  any, else the longest-idle priority one (a PLC reconnecting after a cable pull finds
  its own dead connection there);
- at the limit, anyone else is refused (accepted and closed at once, counted), so a
  flood cannot push out the clients already served;
- a connection without a complete request for `idle_timeout_s` is closed (a slowloris
  client trickling bytes never completes one).
"""
from __future__ import annotations

import ipaddress
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Hashable

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def parse_networks(entries: Iterable[str]) -> tuple[Network, ...]:
    """Networks of "192.168.10.5" / "10.0.0.0/24" entries (ValueError names a bad one)."""
    return tuple(ipaddress.ip_network(entry, strict=False) for entry in entries)


def address_in(peer_ip: str | None, networks: Sequence[Network]) -> bool:
    """Whether the peer's address (IPv4-mapped IPv6 read as IPv4) is in any network."""
    if peer_ip is None:
        return False
    try:
        address = ipaddress.ip_address(peer_ip.split("%", 1)[0])
    except ValueError:
        return False
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return any(address in network for network in networks)


@dataclass(frozen=True, slots=True)
class Connection:
    key: Hashable
    priority: bool
    #: When its last complete request arrived (or it connected), monotonic seconds.
    last_request_s: float


@dataclass(frozen=True, slots=True)
class Admission:
    admitted: bool
    #: The connection to close to make room, if any.
    evict: Hashable | None = None


def admit(newcomer_priority: bool, others: Sequence[Connection], max_connections: int) -> Admission:
    """Whether a new connection may stay, given the `others` already admitted."""
    if len(others) < max_connections:
        return Admission(True)
    if not newcomer_priority:
        return Admission(False)
    ordinary = [c for c in others if not c.priority]
    candidates = ordinary or list(others)
    oldest = min(candidates, key=lambda c: c.last_request_s)
    return Admission(True, evict=oldest.key)


def idle(connections: Iterable[Connection], now_s: float, idle_timeout_s: float) -> list[Hashable]:
    """Keys of the connections without a complete request for `idle_timeout_s` (0: never)."""
    if idle_timeout_s <= 0:
        return []
    return [c.key for c in connections if now_s - c.last_request_s >= idle_timeout_s]
