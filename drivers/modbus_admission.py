"""Which Modbus TCP connections the server keeps: a limit, priority clients, idle time.

Pure decisions (no sockets), so they are tested on their own. The server asks
`admit()` for each new connection and `idle()` on a timer.

Policy, chosen so that no peer can hold the gateway — the PLC is never locked out, a
new client gets in, and the process never runs out of file descriptors (with an
open-file limit of 1 024, 1 100 idle connections used to stop every accept):
- below `max_connections`: everyone gets in;
- at the limit, a newcomer gets in by closing the connection that has done least
  (`least_active`): one that never completed a request before any that did, then the
  one idle longest (the time since its last complete request). A client polling every
  cycle is idle for less than a cycle, so idle connections, a flood of new ones and a
  slowloris (one request a minute, under the idle timeout) are closed before it;
- a priority client (an address in write_allow or priority_clients) is never closed for
  a non-priority newcomer: a non-priority newcomer finds only priority connections →
  refused (accepted and closed at once, counted). A priority newcomer closes a
  non-priority one if there is any, else the priority one that has done least (a PLC
  reconnecting after a cable pull finds its own dead connection there);
- a connection without a complete request for `idle_timeout_s` is closed (a slowloris
  client trickling bytes never completes one).
"""
from __future__ import annotations

import ipaddress
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass

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
    #: Complete requests it has made.
    requests: int = 0


@dataclass(frozen=True, slots=True)
class Admission:
    admitted: bool
    #: The connection to close to make room, if any.
    evict: Hashable | None = None


def least_active(connections: Iterable[Connection]) -> Connection:
    """The connection that has done least: never a complete request before one that made
    some, then the one idle longest."""
    return min(connections, key=lambda c: (c.requests > 0, c.last_request_s))


def admit(newcomer_priority: bool, others: Sequence[Connection], max_connections: int) -> Admission:
    """Whether a new connection may stay, given the `others` already admitted, and which
    one to close for it."""
    if len(others) < max_connections:
        return Admission(True)
    ordinary = [c for c in others if not c.priority]
    if ordinary:
        return Admission(True, evict=least_active(ordinary).key)
    if not newcomer_priority:  # a priority client is never closed for anyone else
        return Admission(False)
    return Admission(True, evict=least_active(others).key)


def idle(connections: Iterable[Connection], now_s: float, idle_timeout_s: float) -> list[Hashable]:
    """Keys of the connections without a complete request for `idle_timeout_s` (0: never)."""
    if idle_timeout_s <= 0:
        return []
    return [c.key for c in connections if now_s - c.last_request_s >= idle_timeout_s]
