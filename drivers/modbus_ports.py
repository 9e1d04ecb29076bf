"""Why a Modbus port cannot be used, in one line: the TCP listen address, the RTU serial port.

pymodbus reports a failed listen or serial open as a bare "Could not start listen"
(the cause only in its own warning), and lets a `termios.error` from pyserial escape as a
traceback (a pty refuses parity E: `termios.error: (22, 'Invalid argument')` — on the
second attempt; the first one is accepted and the parity silently dropped, so the probe
reads the settings back). These
functions find the cause with the same system calls, so the server can say it and the
daemon can decide: a port that is missing may appear later (retry); settings a port
cannot take, or a TCP port in use, will not fix themselves (exit 3).
"""
from __future__ import annotations

import errno
import os
import socket
import termios
from dataclasses import dataclass

import serial

#: errno values that mean "the device is not there (yet)": unplugged USB adapter,
#: a udev link not created yet, a pty whose other end is gone.
_MISSING = frozenset({errno.ENOENT, errno.ENODEV, errno.ENXIO})


@dataclass(frozen=True, slots=True)
class RtuPortProblem:
    #: One line: what, where, why.
    reason: str
    #: True when the port is absent (worth retrying); False when it cannot take the settings
    #: or cannot be opened for another reason that waiting will not fix.
    missing: bool


def probe_rtu_port(port: str, baudrate: int, parity: str, bytesize: int, stopbits: int) -> RtuPortProblem | None:
    """Open and close `port` with the RTU settings (blocking: call it in a thread)."""
    settings = f"{baudrate} baud, {bytesize}{parity}{stopbits}"
    try:
        handle = serial.serial_for_url(port, baudrate=baudrate, parity=parity, bytesize=bytesize,
                                       stopbits=stopbits, exclusive=True)
    except termios.error as err:  # not an OSError: tcsetattr refused the line settings
        code, text = (err.args + (None, None))[:2]
        why = text or str(err)
        return RtuPortProblem(f"RTU port {port} cannot take {settings}: {why} (errno {code})", missing=False)
    except ValueError as err:  # pyserial's own checks (e.g. a baud rate it cannot set)
        return RtuPortProblem(f"RTU port {port} cannot take {settings}: {err}", missing=False)
    except serial.SerialException as err:
        if err.errno in _MISSING:
            return RtuPortProblem(f"RTU port {port} missing ({os.strerror(err.errno)})", missing=True)
        return RtuPortProblem(f"RTU port {port} cannot be opened: {err}", missing=False)
    try:
        kept = _parity_kept(handle, parity)
    finally:
        handle.close()
    if not kept:
        # a Linux pty drops PARENB silently the first time and refuses it (EINVAL) after
        return RtuPortProblem(f"RTU port {port} cannot take {settings}: the port does not keep parity "
                              f"{parity} (a pseudo-terminal cannot)", missing=False)
    return None


def _parity_kept(handle: serial.SerialBase, parity: str) -> bool:
    """Whether a tty's line settings read back with the parity asked for (True where
    there is no tty to ask: a pyserial URL)."""
    try:
        cflag = termios.tcgetattr(handle.fileno())[2]
    except (AttributeError, OSError, termios.error, serial.SerialException):
        return True
    wanted = {"N": 0, "E": termios.PARENB, "O": termios.PARENB | termios.PARODD}[parity]
    return cflag & (termios.PARENB | termios.PARODD) == wanted


def tcp_listen_problem(host: str, port: int) -> str:
    """Why listening on (host, port) fails, found by trying it; a generic line if it works now."""
    return tcp_listen_check(host, port) or f"cannot listen on {host}:{port} (it is free now: try again)"


def tcp_listen_check(host: str, port: int) -> str | None:
    """Why listening on (host, port) would fail now, found by binding it (and closing at
    once); None when it would work. Port 0 checks only the address."""
    try:
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        return f"Modbus TCP host {host!r} does not resolve: {err.strerror}"
    family, _, _, _, address = infos[0]
    try:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server does
            probe.bind(address)
    except OSError as err:
        if err.errno == errno.EADDRINUSE:
            return f"port {port} already in use on {host} (another Modbus server or gateway?)"
        if err.errno == errno.EACCES:
            return f"port {port} on {host} needs privileges (ports below 1024: CAP_NET_BIND_SERVICE)"
        if err.errno == errno.EADDRNOTAVAIL:
            return f"address {host} is not an address of this machine"
        return f"cannot listen on {host}:{port}: {err.strerror or err}"
    return None
