"""Which Modbus TCP connections the server keeps: a limit, priority clients, idle time.

The decisions are pure (no sockets), so they are tested on their own: `admit()` for each
new connection, `idle()` on a timer. `ConnectionTable` applies them to the server's
connections (any object with the `Peer` methods) and says what it did in the peer log.

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
import logging
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from .peer_log import PeerLogLimiter

log = logging.getLogger(__name__)

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


class Peer(Protocol):
    """What the table needs of a connection (the server's request handler)."""

    peer_ip: str | None
    source: str
    priority: bool

    def connection(self) -> Connection: ...

    def close_connection(self, abort: bool) -> None: ...


class ConnectionTable:
    """The admitted TCP connections, in admission order, kept to the policy above."""

    def __init__(self, max_connections: int, priority_networks: Sequence[Network], idle_timeout_s: float,
                 peer_log: PeerLogLimiter, count: Callable[..., None]) -> None:
        self._max_connections = max_connections
        self._priority_networks = tuple(priority_networks)
        self._idle_timeout_s = idle_timeout_s
        self._peer_log = peer_log
        self._count = count  # count(refused_connections=1): the server's counters
        self._peers: dict[int, Peer] = {}

    def admit(self, peer: Peer) -> bool:
        """Whether a new connection may stay (closing another for it if need be); sets
        its `priority`."""
        peer.priority = address_in(peer.peer_ip, self._priority_networks)
        decision = admit(peer.priority, [p.connection() for p in self._peers.values()], self._max_connections)
        if not decision.admitted:
            self._count(refused_connections=1)
            self._peer_log.note(peer.peer_ip or "?", "refused",
                                f"Modbus connection refused: {self._max_connections} open (max_connections)")
            return False
        if decision.evict is not None:
            victim = self._peers.get(decision.evict)
            if victim is not None:
                self._peer_log.note(victim.peer_ip or "?", "evicted",
                                    f"Modbus connection {victim.source} closed at max_connections: it had done "
                                    f"least, room for {'priority ' if peer.priority else ''}client "
                                    f"{peer.peer_ip}")
                victim.close_connection(abort=True)
        self._peers[id(peer)] = peer
        return True

    def release(self, peer: Peer) -> None:
        """It no longer counts against max_connections (closed, or closing)."""
        self._peers.pop(id(peer), None)

    def close_idle(self, now_s: float) -> None:
        """Close (gracefully) the connections without a complete request for idle_timeout_s."""
        for key in idle([p.connection() for p in self._peers.values()], now_s, self._idle_timeout_s):
            peer = self._peers.get(key)
            if peer is not None:
                log.debug("Modbus connection %s idle for %.0f s: closing", peer.source, self._idle_timeout_s)
                peer.close_connection(abort=False)

    def clear(self) -> None:
        self._peers.clear()
