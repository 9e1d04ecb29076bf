"""Tests in this directory run inside the SocketCAN VM only (tests/vmcan/harness.py).

On the host there is no vcan0, so the host's pytest run must not collect
them: an outer test in tests/ boots the VM and runs them there instead
(see tests/can/test_socketcan_vm.py). The harness sets ADXLGW_IN_VM=1.
"""

import os

if os.environ.get("ADXLGW_IN_VM") != "1":
    collect_ignore_glob = ["test_*.py"]
