"""bodebench bus drivers: CAN (python-can) and serial (pyserial).

The names below are imported on first use, so that importing one submodule (``bodebench.drivers.errors``, say)
does not import them all.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "Codec": "codec", "Message": "codec", "Signal": "codec",
    "BusHealth": "driver", "Driver": "driver", "FeedbackSample": "driver", "Unwrapper": "driver",
    "DriverError": "errors", "DriverInitError": "errors", "DriverOperationError": "errors",
    "DriverTimeoutError": "errors", "DriveFaultError": "errors", "LayoutError": "errors",
    "CanopenDriver": "canopen_link", "CanopenSetup": "canopen_link",
    "Layout": "layout", "default_layout": "layout",
    "CanPort": "ports", "Frame": "ports", "FramePort": "ports", "SerialPort": "ports",
    "AsciiDeframer": "serial_framing", "BinaryDeframer": "serial_framing", "crc16_ccitt_false": "serial_framing",
    "encode_ascii": "serial_framing", "encode_binary": "serial_framing",
}

if TYPE_CHECKING:
    from .canopen_link import CanopenDriver, CanopenSetup
    from .codec import Codec, Message, Signal
    from .driver import BusHealth, Driver, FeedbackSample, Unwrapper
    from .errors import (
        DriveFaultError,
        DriverError,
        DriverInitError,
        DriverOperationError,
        DriverTimeoutError,
        LayoutError,
    )
    from .layout import Layout, default_layout
    from .ports import CanPort, Frame, FramePort, SerialPort
    from .serial_framing import AsciiDeframer, BinaryDeframer, crc16_ccitt_false, encode_ascii, encode_binary


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value

__all__ = [
    "AsciiDeframer",
    "BinaryDeframer",
    "BusHealth",
    "CanPort",
    "CanopenDriver",
    "CanopenSetup",
    "Codec",
    "Driver",
    "DriverError",
    "DriverInitError",
    "DriverOperationError",
    "DriverTimeoutError",
    "DriveFaultError",
    "FeedbackSample",
    "Frame",
    "FramePort",
    "Layout",
    "LayoutError",
    "Message",
    "Signal",
    "SerialPort",
    "Unwrapper",
    "crc16_ccitt_false",
    "default_layout",
    "encode_ascii",
    "encode_binary",
]
