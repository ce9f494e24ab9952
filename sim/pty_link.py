"""Pseudo-terminal links for the simulated controller.

``Pty`` makes a raw pseudo-terminal pair: the controller keeps the master
side, the instrument opens the slave's real tty path with pyserial (or
python-can's ``slcan`` interface). ``FdStream`` gives the master descriptor
the small file interface the serial frame port reads, and
``SlcanAdapterPort`` makes the controller pose as an SLCAN (Lawicel ASCII)
USB-CAN adapter on it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import time

from bodebench.drivers.ports import Frame, FramePort

MAX_LINE = 64

POSIX_ONLY = ("the pseudo-terminal simulators (serial, slcan) need a POSIX system (Linux, macOS) with termios "
              "and pseudo-terminals; here the simulated drive runs on a python-can virtual bus "
              '([can] interface = "virtual") or in-process (bodebench simulate)')
"""Why a pseudo-terminal cannot be made on this platform."""


class PtyUnavailable(OSError):
    """This platform has no pseudo-terminals (Windows): the message says where the simulated drive can run."""


def pty_available() -> bool:
    """Whether pseudo-terminals can be made here (``tty``/``termios`` importable and ``os.openpty`` present)."""
    try:
        import tty  # noqa: F401
    except ImportError:
        return False
    return hasattr(os, "openpty") and hasattr(os, "ttyname")


class Pty:
    """A raw pseudo-terminal pair: the controller keeps ``master``; the instrument opens ``path``.

    The slave descriptor stays open on this side so the link survives the
    instrument closing and reopening the path (a master read would fail with
    EIO while nobody holds the slave).
    """

    def __init__(self) -> None:
        """Raises :class:`PtyUnavailable` where the platform has no pseudo-terminals."""
        if not pty_available():
            raise PtyUnavailable(POSIX_ONLY)
        import tty

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)

    def close(self) -> None:
        """Close both sides."""
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class FdStream:
    """File-like view of a non-blocking descriptor: read(n) returns what is there (up to timeout), write(data)."""

    def __init__(self, fd: int, timeout: float = 0.0) -> None:
        self.fd = fd
        self.timeout = timeout

    def fileno(self) -> int:
        """The descriptor."""
        return self.fd

    @property
    def in_waiting(self) -> int:
        """4096 when bytes are ready to be read, else 0 (the count itself is unknown)."""
        ready, _, _ = select.select([self.fd], [], [], 0)
        return 4096 if ready else 0

    def read(self, n: int = 4096) -> bytes:
        """At most ``n`` bytes, waiting up to ``timeout`` s for the first (b"" when none came)."""
        ready, _, _ = select.select([self.fd], [], [], self.timeout)
        if not ready:
            return b""
        try:
            return os.read(self.fd, n)
        except OSError as exc:  # EIO: nobody holds the slave side
            if exc.errno in (errno.EIO, errno.EAGAIN):
                return b""
            raise

    def write(self, data: bytes) -> int:
        """Write all of ``data``, waiting while the descriptor takes no more; returns its length."""
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 0.1)
                continue
            view = view[n:]
        return len(data)

    def flush(self) -> None:
        """Writes go straight to the descriptor."""

    def close(self) -> None:
        """The descriptor belongs to the ``Pty``; closing the stream leaves it open."""


class SlcanAdapterPort(FramePort):
    """The controller's side of an SLCAN adapter: Lawicel ASCII commands in, frames out, on a descriptor.

    Answers the configuration commands python-can's ``slcan`` interface sends
    (``S0``-``S8``, ``O``, ``L``, ``C``, ``V``, ``N``, ``Z``, ``F``) with a
    carriage return, acknowledges transmitted frames with ``z``/``Z``, and
    writes frames to the host as ``tIIILDD..`` / ``TIIIIIIIILDD..`` lines.
    Malformed lines are answered with BELL and counted as errors.
    """

    def __init__(self, fd: int) -> None:
        super().__init__(f"SLCAN adapter fd {fd}", "can")
        self._stream = FdStream(fd)
        self._buffer = bytearray()
        self.is_open = False

    def _send(self, frame: Frame) -> None:
        if frame.is_error:  # the SLCAN protocol carries no error frames
            return
        ident = f"T{frame.id:08X}" if frame.extended else f"t{frame.id:03X}"
        self._stream.write(f"{ident}{len(frame.data)}{bytes(frame.data).hex().upper()}\r".encode())

    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        frames: list[Frame] = []
        deadline = time.monotonic() + timeout
        while True:
            self._stream.timeout = max(0.0, deadline - time.monotonic())
            chunk = self._stream.read(4096)
            if chunk:
                self._buffer.extend(chunk)
                frames.extend(self._parse())
            if frames or not chunk and time.monotonic() >= deadline:
                return frames

    def _parse(self) -> list[Frame]:
        frames: list[Frame] = []
        while True:
            end = self._buffer.find(b"\r")
            if end < 0:
                if len(self._buffer) > MAX_LINE:
                    self._buffer.clear()
                    self._count_error()
                return frames
            line = bytes(self._buffer[:end]).decode("ascii", "replace")
            del self._buffer[:end + 1]
            frame = self._command(line)
            if frame is not None:
                frames.append(frame)

    def _command(self, line: str) -> Frame | None:
        if not line:
            return None
        kind = line[0]
        try:
            if kind in "tT":
                width = 3 if kind == "t" else 8
                ident = int(line[1:1 + width], 16)
                dlc = int(line[1 + width])
                data = bytes.fromhex(line[2 + width:2 + width + 2 * dlc])
                if len(data) != dlc or dlc > 8:
                    raise ValueError("length")
                self._stream.write(b"z\r" if kind == "t" else b"Z\r")
                return Frame(ident, data, kind == "T", time.time())
            if kind in "OL":
                self.is_open = True
            elif kind == "C":
                self.is_open = False
            elif kind == "V":
                self._stream.write(b"V1013\r")
                return None
            elif kind == "N":
                self._stream.write(b"NBB01\r")
                return None
            elif kind not in "SsZFXW":
                raise ValueError(kind)
            self._stream.write(b"\r")
        except ValueError:
            self._stream.write(b"\a")
            self._count_error()
        return None

    def _count_error(self) -> None:
        self._note_error("malformed SLCAN line")

    def _close(self) -> None:
        """The descriptor belongs to the ``Pty`` that made it."""
