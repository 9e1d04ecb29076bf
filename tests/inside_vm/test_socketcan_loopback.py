"""Real SocketCAN on vcan0, run inside the qemu VM by tests/can/test_socketcan_vm.py.

These exercise the kernel's CAN stack (can, can-raw, vcan), not python-can's
virtual bus: a frame written by one raw socket must come back, unchanged, on
another socket bound to the same interface.
"""

import contextlib
import re
import shutil
import subprocess
import time

import can
import pytest

CHANNEL = "vcan0"
RECEIVE_TIMEOUT_S = 2.0
CANDUMP_WAIT_S = 10.0


def _bus() -> can.BusABC:
    return can.Bus(interface="socketcan", channel=CHANNEL)


@pytest.mark.parametrize(
    ("arbitration_id", "is_extended_id", "data"),
    [
        (0x123, False, bytes([0xDE, 0xAD, 0xBE, 0xEF])),
        (0x7FF, False, b""),
        (0x1ABCDE0F, True, bytes(range(8))),
    ],
)
def test_python_can_frame_crosses_vcan_between_two_buses(arbitration_id, is_extended_id, data):
    with _bus() as sender, _bus() as receiver:
        sent = can.Message(arbitration_id=arbitration_id, is_extended_id=is_extended_id, data=data)
        sender.send(sent)
        received = receiver.recv(timeout=RECEIVE_TIMEOUT_S)
        assert received is not None, f"no frame on {CHANNEL} within {RECEIVE_TIMEOUT_S} s"
        assert received.arbitration_id == arbitration_id
        assert received.is_extended_id == is_extended_id
        assert bytes(received.data) == data
        assert received.dlc == len(data)
        assert received.channel == CHANNEL
        # By default a socket does not receive the frames it sent itself.
        assert sender.recv(timeout=0.2) is None


def test_candump_captures_frame_sent_by_cansend():
    missing = [tool for tool in ("candump", "cansend") if shutil.which(tool) is None]
    assert not missing, f"{missing} not found: run scripts/install-vm-deps.sh"
    dump = subprocess.Popen(
        ["candump", "-n", "1", CHANNEL], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        # candump gives no sign of having bound its socket, so send until it
        # has seen a frame and exited (-n 1); each try is the same frame.
        deadline = time.monotonic() + CANDUMP_WAIT_S
        while dump.poll() is None and time.monotonic() < deadline:
            subprocess.run(["cansend", CHANNEL, "123#DEADBEEF"], check=True)
            with contextlib.suppress(subprocess.TimeoutExpired):
                dump.wait(timeout=0.1)
        stdout, stderr = dump.communicate(timeout=1.0)
    finally:
        if dump.poll() is None:
            dump.kill()
            dump.wait()
    assert dump.returncode == 0, f"candump failed: {stderr}"
    # e.g. "  vcan0  123   [4]  DE AD BE EF"
    assert re.fullmatch(r"\s*vcan0\s+123\s+\[4\]\s+DE AD BE EF\s*", stdout), repr(stdout)
