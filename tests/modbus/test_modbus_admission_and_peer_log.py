"""The Modbus server's pure decisions on their own: who gets a connection, which are idle,
and how often a peer's errors reach the log."""
from __future__ import annotations

import logging

import pytest

from drivers.modbus_admission import Admission, Connection, address_in, admit, idle, parse_networks
from drivers.peer_log import MAX_TRACKED_PEERS, OTHER_PEERS, PeerLogLimiter


def conn(key: str, priority: bool = False, last_s: float = 0.0, requests: int = 1) -> Connection:
    return Connection(key=key, priority=priority, last_request_s=last_s, requests=requests)


def test_below_the_limit_everyone_gets_in() -> None:
    assert admit(False, [conn("a")], 2) == Admission(True)


def test_at_the_limit_a_newcomer_closes_the_connection_that_has_done_least() -> None:
    # a slowloris (its last request 50 s ago) goes before a PLC polling every cycle
    others = [conn("plc", False, 99.9), conn("slowloris", False, 50.0), conn("poller", False, 99.0)]
    assert admit(False, others, 3) == Admission(True, evict="slowloris")
    # one that never completed a request goes first, however recent (a flood's connection)
    others.append(conn("idle-new", False, 99.95, requests=0))
    assert admit(False, others, 4) == Admission(True, evict="idle-new")


def test_a_priority_client_is_never_closed_for_a_non_priority_newcomer() -> None:
    assert admit(False, [conn("a", False, 9.0), conn("b", True, 0.0, requests=0)], 2) == Admission(True, evict="a")
    assert admit(False, [conn("a", True), conn("b", priority=True)], 2) == Admission(False)


def test_a_priority_client_takes_the_place_of_the_longest_idle_ordinary_one() -> None:
    others = [conn("plc", True, 0.0), conn("hmi", False, 5.0), conn("scan", False, 3.0)]
    assert admit(True, others, 3) == Admission(True, evict="scan")


def test_among_priority_clients_only_the_longest_idle_one_goes() -> None:
    others = [conn("plc-old", True, 1.0), conn("plc-new", True, 9.0)]
    assert admit(True, others, 2) == Admission(True, evict="plc-old")


def test_idle_connections() -> None:
    connections = [conn("a", last_s=0.0), conn("b", last_s=9.5)]
    assert idle(connections, now_s=10.0, idle_timeout_s=5.0) == ["a"]
    assert idle(connections, now_s=10.0, idle_timeout_s=0.0) == []  # 0: never


@pytest.mark.parametrize("peer, inside", [("10.0.0.7", True), ("10.0.1.7", False), ("::ffff:10.0.0.9", True),
                                          ("fe80::1%eth0", False), ("192.168.1.5", True), ("garbage", False),
                                          (None, False)])
def test_addresses_in_networks(peer, inside: bool) -> None:
    networks = parse_networks(["10.0.0.0/24", "192.168.1.5"])
    assert address_in(peer, networks) is inside


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_one_line_per_peer_and_interval_with_the_count(caplog) -> None:
    clock = Clock()
    limiter = PeerLogLimiter(logging.getLogger("test.peers"), interval_s=10.0, clock=clock)
    with caplog.at_level(logging.WARNING, logger="test.peers"):
        for _ in range(100):
            limiter.note("10.0.0.7", "bad frame", "bad MBAP header")
            clock.now += 0.01
        limiter.note("10.0.0.8", "bad frame", "bad MBAP header")  # another peer: its own line
        clock.now = 10.5
        limiter.note("10.0.0.7", "bad frame", "bad MBAP header")
        clock.now = 25.0
        limiter.note("10.0.0.7", "bad frame", "bad MBAP header")
        clock.now = 40.0
        limiter.flush()
    messages = [r.getMessage() for r in caplog.records]
    assert messages == [
        "10.0.0.7: bad MBAP header",
        "10.0.0.8: bad MBAP header",
        "10.0.0.7: bad MBAP header (99 more since the last line)",
        "10.0.0.7: bad MBAP header",
    ]
    assert limiter.lines == 4


def test_held_back_counts_are_written_by_flush_and_quiet_peers_forgotten(caplog) -> None:
    clock = Clock()
    limiter = PeerLogLimiter(logging.getLogger("test.peers"), interval_s=1.0, clock=clock)
    with caplog.at_level(logging.WARNING, logger="test.peers"):
        for _ in range(5):
            limiter.note("a", "refused", "refused")
        clock.now = 1.0
        limiter.flush()
        clock.now = 2.0
        limiter.flush()  # nothing new: forgotten, no line
        limiter.note("a", "refused", "refused")  # a fresh start: logged at once
    assert [r.getMessage() for r in caplog.records] == [
        "a: refused", "a: refused (4 times since the last line)", "a: refused"]


def test_the_table_of_peers_is_bounded(caplog) -> None:
    limiter = PeerLogLimiter(logging.getLogger("test.peers"), interval_s=60.0, clock=Clock())
    with caplog.at_level(logging.WARNING, logger="test.peers"):
        for i in range(MAX_TRACKED_PEERS + 1000):
            limiter.note(f"peer{i}", "refused", "refused")
    assert len(caplog.records) == MAX_TRACKED_PEERS + 1
    assert caplog.records[-1].getMessage() == f"{OTHER_PEERS}: refused"
