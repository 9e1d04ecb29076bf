import json
import os
import socket

from gateway.daemon.sd_notify import SystemdNotifier
from gateway.daemon.state_store import PersistentState, StateStore


def test_notifier_sends_datagrams_to_the_notify_socket(tmp_path):
    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.settimeout(2)
    try:
        n = SystemdNotifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"})
        assert n.enabled and n.watchdog_interval_s == 2.0
        n.ready("serving")
        n.watchdog()
        n.stopping()
        got = [server.recv(4096).decode() for _ in range(3)]
        assert got == ["READY=1\nSTATUS=serving", "WATCHDOG=1", "STOPPING=1"]
        n.close()
    finally:
        server.close()


def test_notifier_is_a_no_op_outside_systemd_and_ignores_other_pids_watchdog():
    n = SystemdNotifier({"WATCHDOG_USEC": "1000", "WATCHDOG_PID": str(os.getpid() + 1)})
    assert not n.enabled and n.watchdog_interval_s is None
    n.ready()  # no socket: nothing happens, nothing raises


def test_notifier_survives_a_vanished_socket(tmp_path):
    n = SystemdNotifier({"NOTIFY_SOCKET": str(tmp_path / "gone")})
    n.ready()  # logged, not raised


def test_state_round_trip_and_atomic_replace(tmp_path):
    store = StateStore(tmp_path / "sub" / "state.json")
    assert store.load() == PersistentState()
    assert store.save(PersistentState(tare_offset_m=0.125, bias_estimate_mps2=0.01, saved_at_unix_s=5.0))
    assert store.load().tare_offset_m == 0.125
    assert not list((tmp_path / "sub").glob(".*tmp"))


def test_corrupt_state_starts_unreferenced_and_says_why(tmp_path):
    path = tmp_path / "state.json"
    path.write_text("{ half a file")
    store = StateStore(path)
    assert store.load() == PersistentState()
    assert "unreadable state" in store.last_error
    path.write_text(json.dumps({"version": 99}))
    assert store.load() == PersistentState() and "state version 99" in store.last_error


def test_unwritable_state_is_reported_not_raised(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    store = StateStore(blocker / "state.json")  # parent is a file
    assert store.save(PersistentState()) is False
    assert "cannot save state" in store.last_error


def test_the_board_port_batches_unless_can_sends_per_sample(tmp_path):
    """serial.batch_frames sets how many SAMPLE frames' bytes wake the daemon; CAN's
    mixed mode (min_interval_ms ≥ 0, a frame pair per sample) needs a wakeup per sample."""
    from drivers.board_protocol import SAMPLE_FRAME_LENGTH
    from gateway.config import validate
    from gateway.daemon.settings import serial_settings_from

    def wake(**sections):
        cfg = validate({"state": {"path": str(tmp_path / "s.json")}, **sections}, "<test>")
        return serial_settings_from(cfg, "/dev/ttyUSB0").wake_min_bytes

    assert wake() == 5 * SAMPLE_FRAME_LENGTH
    assert wake(serial={"batch_frames": 1}) == SAMPLE_FRAME_LENGTH
    assert wake(serial={"batch_frames": 17}) == 255
    assert wake(can={"min_interval_ms": 0}) == SAMPLE_FRAME_LENGTH
    assert wake(can={"min_interval_ms": 0, "enabled": False}) == 5 * SAMPLE_FRAME_LENGTH


def test_watchdog_is_fed_by_progress_since_the_last_check_not_by_staleness():
    from gateway.daemon.service_tasks import board_alive_for_watchdog

    check_every_s, lost_after_s = 15.0, 1.0  # WatchdogSec=30 s, serial.lost_after_ms = 1000
    assert not board_alive_for_watchdog(100.0, None, check_every_s, lost_after_s)  # no sample yet
    # a board slowed into 3 s bursts (values STALE between them) is slow, not hung: fed
    assert board_alive_for_watchdog(100.0, 97.0, check_every_s, lost_after_s)
    # no sample since the previous check: not fed, so systemd restarts after WatchdogSec
    assert not board_alive_for_watchdog(100.0, 100.0 - check_every_s, check_every_s, lost_after_s)
    # a short WatchdogSec (checks every 0.1 s): the freshness bound is the longer and rules
    assert board_alive_for_watchdog(100.0, 99.5, 0.1, lost_after_s)
    assert not board_alive_for_watchdog(100.0, 98.9, 0.1, lost_after_s)
