"""Errors raised by the drivers (everything that touches a wire).

drivers/ never imports gateway/, so this family stands on its own; the gateway may
wrap or re-export it. Third-party errors (pyserial, struct, OS) are caught at the
driver edge and re-raised as one of these with ``raise ... from err`` so callers
handle one family and still see the original cause.
"""

from __future__ import annotations


class DriverError(Exception):
    """Base of every error a driver raises on purpose."""


class SerialPortError(DriverError):
    """The serial port cannot be opened, or was lost and the source gave up.

    ``port`` names the device path or pyserial URL so the message is actionable.
    """

    def __init__(self, message: str, *, port: str) -> None:
        super().__init__(message)
        self.port = port


class BoardProtocolError(DriverError):
    """A value cannot be expressed in the board protocol (e.g. a field out of range).

    The stream decoder never raises this: bad bytes on the line are counted and
    skipped, not raised.
    """
