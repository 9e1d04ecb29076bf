"""Whether the wires a config names can exist on this machine, asked without opening them.

Used before the daemon starts and by `adxlgw config --check`. Each answer is a
`LinkCheck`: "ok", "missing" (the name is right but the thing is not there now — a
USB adapter not plugged in, a CAN link not created), "invalid" (no such thing can
exist: an interface python-can does not know), or "unchecked" (nothing here can tell,
and the answer says so rather than pretending).
"""
from __future__ import annotations

import os
import socket
from dataclasses import dataclass

from can.interfaces import VALID_INTERFACES

ARPHRD_CAN = 280  # linux/if_arp.h: the link type of can0, vcan0, vxcan …


def _link_type(name: str) -> int | None:
    try:
        with open(f"/sys/class/net/{name}/type", encoding="ascii") as fh:
            return int(fh.read())
    except (OSError, ValueError):  # no sysfs here: the name check above is all we know
        return None


@dataclass(frozen=True)
class LinkCheck:
    verdict: str  # "ok", "missing", "invalid", "unchecked"
    detail: str = ""
    wrong_interface: bool = False  # CAN: the interface name is at fault, not the channel


def check_serial_port(port: str) -> LinkCheck:
    if "://" in port:  # a pyserial URL (socket://, rfc2217://, loop://): only opening it tells
        return LinkCheck("unchecked", f"{port} is a pyserial URL; reachable only when opened")
    if not os.path.exists(port):
        return LinkCheck("missing", f"{port} does not exist")
    return LinkCheck("ok")


def check_can_link(interface: str, channel: str) -> LinkCheck:
    if interface not in VALID_INTERFACES:
        return LinkCheck("invalid", f"python-can has no interface {interface!r} "
                                    f"(known: {', '.join(sorted(VALID_INTERFACES))})", wrong_interface=True)
    if interface == "socketcan":
        try:
            socket.if_nametoindex(channel)
        except OSError:
            return LinkCheck("missing", f"no network interface {channel!r} (ip link show type can lists them)")
        if _link_type(channel) not in (None, ARPHRD_CAN):
            return LinkCheck("invalid", f"network interface {channel!r} is not a CAN interface")
        return LinkCheck("ok")
    if interface == "virtual":
        return LinkCheck("ok", "python-can's in-process virtual bus: no frame leaves this process")
    return LinkCheck("unchecked", f"channel {channel!r} of interface {interface} is found only when opened")
