"""bodebench bus drivers: CAN (python-can) and serial (pyserial)."""

from .codec import Codec, Message, Signal
from .driver import BusHealth, Driver, FeedbackSample, Unwrapper
from .errors import DriverError, DriverInitError, DriverOperationError, DriverTimeoutError, LayoutError
from .layout import Layout, default_layout
from .ports import CanPort, Frame, FramePort, SerialPort
from .serial_framing import AsciiDeframer, BinaryDeframer, crc16_ccitt_false, encode_ascii, encode_binary

__all__ = [
    "AsciiDeframer",
    "BinaryDeframer",
    "BusHealth",
    "CanPort",
    "Codec",
    "Driver",
    "DriverError",
    "DriverInitError",
    "DriverOperationError",
    "DriverTimeoutError",
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
