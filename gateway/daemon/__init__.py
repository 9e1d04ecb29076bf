"""The daemon: a small supervisor (supervisor.Gateway) wiring the board's port, the
sample pipeline (board bytes → estimate, no I/O), the wires (Modbus, CAN), systemd and the
state file. Nothing here is needed by the offline commands."""
from gateway.daemon.supervisor import Gateway

__all__ = ["Gateway"]
