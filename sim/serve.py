"""Running a simulated servo controller on a transport.

- ``ControllerPort``: a direct in-memory link (lockstep; the offline run of a bench config).
- ``serve_can``: on any python-can bus (``virtual`` in-process, ``udp_multicast``, ...) in a thread.
- ``serve_serial_pty`` / ``serve_slcan_pty``: on a pseudo-terminal, posing as a serial drive or as an SLCAN
  USB-CAN adapter; the instrument opens the returned tty path.
- ``run_in_process``: any of the pty transports in a process of its own, reporting the path.
"""

from __future__ import annotations

import collections
import contextlib
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from bodebench.drivers.canopen_link import CanopenSetup
from bodebench.drivers.layout import Layout
from bodebench.drivers.ports import CanPort, Frame, FramePort, SerialPort
from bodebench.sim.canopen_device import ServingCanopen, serve_canopen
from bodebench.sim.controller import ControllerTiming, FeedbackSensing, SimulatedController
from bodebench.sim.faults import CanopenFaults, FaultConfig, FaultyPort, ValueFaults
from bodebench.sim.loop_config import LoopConfig
from bodebench.sim.models import plant_from_table
from bodebench.sim.pty_link import POSIX_ONLY, FdStream, Pty, PtyUnavailable, SlcanAdapterPort, pty_available

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

PTY_TRANSPORTS = ("serial", "slcan")


class _Closable(Protocol):
    """Anything with a ``close()``."""

    def close(self) -> None:
        """Release what it holds."""
        ...


@dataclass(frozen=True)
class SimulatorSpec:
    """A picklable recipe for a simulated controller: plant parameters (``model`` plus its keys, as
    ``sim.models.plant_from_config`` takes them), layout, timing."""

    plant: Mapping[str, Any]
    layout: Layout
    timing: ControllerTiming
    framing: str = "binary"  # serial transport only
    can: Mapping[str, Any] = field(default_factory=dict)  # interface, channel, bitrate, options (CAN buses)
    faults: FaultConfig | None = None
    sensing: FeedbackSensing | None = None
    canopen: CanopenSetup | None = None  # a CiA 402 drive (``layout`` is then ``canopen.layout()``)
    canopen_faults: CanopenFaults | None = None
    loop: LoopConfig = field(default_factory=LoopConfig)  # the drive's own control loop around the plant

    def controller(self) -> SimulatedController:
        """A new controller around a new plant (inside the drive's loop where it has one)."""
        plant = self.loop.around(plant_from_table(self.plant))
        return SimulatedController(plant, self.layout, self.timing,
                                   ValueFaults(self.faults) if self.faults is not None else None,
                                   sensing=self.sensing)

    def wire(self, port: FramePort, raw_write: Callable[[bytes], object] | None = None) -> FramePort:
        """The port the controller serves on, with the configured frame faults (``raw_write`` writes bytes straight
        onto a serial line)."""
        if self.faults is None:
            return port
        encode = port.wire_bytes if isinstance(port, SerialPort) else None
        return FaultyPort(port, self.faults, {m.id for m in self.layout.feedback}, raw_write, encode)


class ControllerPort(FramePort):
    """The host's end of a direct link to a lockstep controller: a sent frame is handled at once."""

    def __init__(self, controller: SimulatedController, transport: str = "can") -> None:
        """transport: the Layout.validate name of the bus this link stands in for."""
        super().__init__("simulated drive (direct)", transport)
        self.controller = controller
        self._inbox: collections.deque[Frame] = collections.deque()

    def _send(self, frame: Frame) -> None:
        self._inbox.extend(self.controller.handle(frame))

    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        frames = list(self._inbox)
        self._inbox.clear()
        return frames

    def _close(self) -> None:
        """Nothing to release."""


class Serving:
    """A controller serving in a background thread; ``close`` stops it and releases the transport."""

    def __init__(self, controller: SimulatedController, port: FramePort,
                 extra: list[_Closable] | None = None) -> None:
        """Serve ``controller`` on ``port`` now; ``extra``: also closed by ``close`` (the pty of the link)."""
        self.controller = controller
        self.port = port
        self.stop = threading.Event()
        self._extra = extra or []
        self.thread = threading.Thread(target=self._serve, name="sim-controller", daemon=True)
        self.error: BaseException | None = None
        self.thread.start()

    def _serve(self) -> None:
        try:
            self.controller.serve(self.port, self.stop)
        except BaseException as exc:  # noqa: BLE001 - reported to whoever closes us
            self.error = exc

    def close(self) -> None:
        """Stop serving, then close the port and ``extra``."""
        self.stop.set()
        self.thread.join(timeout=5)
        try:
            self.port.close()
        finally:
            for item in self._extra:
                item.close()


def serve_can(spec: SimulatorSpec) -> Serving | ServingCanopen:
    """Serve on a python-can bus opened from ``spec.can`` (for ``virtual``: in this process); with
    ``spec.canopen`` as a CiA 402 drive (sim.canopen_device)."""
    can = dict(spec.can)
    if spec.canopen is not None:
        return serve_canopen(spec.controller(), spec.canopen, can, spec.canopen_faults)
    port = CanPort.open(can["interface"], can.get("channel"), can.get("bitrate"), can.get("options", {}),
                        fd=bool(can.get("fd", False)))
    return Serving(spec.controller(), spec.wire(port))


def serve_serial_pty(spec: SimulatorSpec) -> tuple[Serving, str]:
    """Serve the serial protocol on a new pseudo-terminal; returns the tty path the instrument opens (POSIX only:
    SimulatorStartError elsewhere)."""
    pty = _new_pty()
    stream = FdStream(pty.master)
    port = SerialPort(stream, spec.framing, spec.layout)
    return Serving(spec.controller(), spec.wire(port, stream.write), [pty]), pty.path


def serve_slcan_pty(spec: SimulatorSpec) -> tuple[Serving, str]:
    """Pose as an SLCAN adapter on a new pseudo-terminal; returns the path for python-can's ``slcan`` interface
    (POSIX only: SimulatorStartError elsewhere)."""
    pty = _new_pty()
    return Serving(spec.controller(), spec.wire(SlcanAdapterPort(pty.master)), [pty]), pty.path


class SimulatorStartError(RuntimeError):
    """The simulated controller could not be started (the message says why)."""


def _new_pty() -> Pty:
    try:
        return Pty()
    except PtyUnavailable as exc:
        raise SimulatorStartError(str(exc)) from None


def _process_main(spec: SimulatorSpec, transport: str, conn: Connection) -> None:
    """The simulator process: serve, report the tty path (or the error) on ``conn``, stop when ``conn`` says so."""
    try:
        serving, path = (serve_slcan_pty if transport == "slcan" else serve_serial_pty)(spec)
    except Exception as exc:  # noqa: BLE001 - reported to the parent as text
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("path", path))
    try:
        conn.recv()  # anything, or the pipe closing, ends the simulator
    except (EOFError, OSError):
        pass
    finally:
        serving.close()


class SimulatorProcess:
    """A pty-transport simulator in its own process (the drive on the far side of a real tty)."""

    def __init__(self, spec: SimulatorSpec, transport: str) -> None:
        import multiprocessing as mp

        if transport not in PTY_TRANSPORTS:
            raise ValueError(f"transport must be one of {PTY_TRANSPORTS}")
        if not pty_available():
            raise SimulatorStartError(POSIX_ONLY)
        ctx = mp.get_context("spawn")
        self._conn, theirs = ctx.Pipe()
        self.process = ctx.Process(target=_process_main, args=(spec, transport, theirs), daemon=True,
                                   name=f"sim-controller-{transport}")
        self.process.start()
        theirs.close()
        try:
            if not self._conn.poll(30):
                raise SimulatorStartError("simulated controller did not start within 30 s")
            kind, text = self._conn.recv()
        except (EOFError, OSError):
            kind, text = "error", "simulated controller process ended at start"
        except SimulatorStartError:
            self.process.terminate()
            raise
        if kind != "path":
            self.process.join(timeout=5)
            raise SimulatorStartError(f"simulated controller: {text}")
        self.path: str = text

    def close(self) -> None:
        """Stop the simulator process (terminated when it has not ended 5 s later)."""
        with contextlib.suppress(OSError, BrokenPipeError):
            self._conn.send("stop")
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.terminate()
