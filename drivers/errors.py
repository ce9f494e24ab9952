"""Exception hierarchy of the bus drivers, grouped by the phase in which they occur.

- ``LayoutError`` (a ``ValueError``): a frame layout, signal value or configuration table is invalid.
- ``DriverInitError``: opening or configuring an interface failed.
- ``DriverOperationError``: sending or receiving on an open interface failed.
- ``DriverTimeoutError``: an interface operation did not complete within its time limit.
- ``DriveFaultError``: the drive itself reported a fault or stopped answering its protocol (a CANopen emergency
  message, a CiA 402 fault state, a lost heartbeat) or refused to enable.

Backends catch vendor exceptions (``can.CanError`` family, ``serial.SerialException``, ``OSError``) at their
boundary and re-raise them as one of the ``DriverError`` subclasses, with the original exception as ``__cause__``
and a message naming the interface, channel or port.
"""

from __future__ import annotations

__all__ = [
    "DriverError",
    "DriverInitError",
    "DriverOperationError",
    "DriverTimeoutError",
    "DriveFaultError",
    "LayoutError",
]


class DriverError(Exception):
    """Base class of every error raised by a frame port or driver at run time."""


class DriverInitError(DriverError):
    """Opening or configuring an interface (CAN bus, serial port) failed."""


class DriverOperationError(DriverError):
    """Sending or receiving on an open interface failed, or the interface is closed."""


class DriverTimeoutError(DriverOperationError):
    """An interface operation did not complete within its time limit."""


class DriveFaultError(DriverOperationError):
    """The drive reported a fault (CANopen EMCY, CiA 402 fault state), fell silent (no heartbeat) or refused to
    enable; the message names the node and what it said."""


class LayoutError(ValueError):
    """A frame layout, a signal value or a layout configuration table is invalid."""
