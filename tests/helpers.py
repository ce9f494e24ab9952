"""Helpers shared by the test modules (imported as ``helpers``: pytest puts tests/ on sys.path)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from bodebench.drivers.layout import default_layout

if TYPE_CHECKING:
    from bodebench.bench.events import SessionError
    from bodebench.bench.session import BenchSession


class FrameRecorder:
    """A listening node on the virtual bus that keeps every frame it sees."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.frames: list[can.Message] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.frames.append(msg)

    def frames_seen(self) -> list[can.Message]:
        """Stop listening and return every frame, those still queued when the reader stopped included."""
        self.stop.set()
        self.thread.join()
        while (msg := self.bus.recv(0.05)) is not None:
            self.frames.append(msg)
        self.bus.shutdown()
        return self.frames


class BusRecorder(FrameRecorder):
    """A third node on the virtual bus that records every setpoint and enable/disable frame."""

    def __init__(self, channel: str) -> None:
        self.layout = default_layout()
        super().__init__(channel)

    def close(self) -> tuple[float, bool]:
        """(last setpoint sent, whether a disable frame followed it)."""
        self.frames_seen()
        sp, dis = self.layout.setpoint, self.layout.disable
        setpoints = [i for i, m in enumerate(self.frames) if m.arbitration_id == sp.id]
        last = setpoints[-1]
        value = sp.decode(bytes(self.frames[last].data))["setpoint"]
        disabled = any(m.arbitration_id == dis.id and bytes(m.data) == bytes(dis.data)
                       for m in self.frames[last:])
        return value, disabled


def interrupt_after(directory: Path, rows: int) -> None:
    """Leave a results directory as a sweep stopped after its first ``rows`` rows leaves it: the later rows gone
    from response.csv, and from the checksums its sidecar records (an interrupted run never wrote them)."""
    import json

    from bodebench.io.results import CHECKSUMS, CSV_NAME, SIDECAR_NAME

    csv = directory / CSV_NAME
    lines = csv.read_text().splitlines(keepends=True)
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    csv.write_text("".join(lines[:header + 1 + rows]))
    sidecar = json.loads((directory / SIDECAR_NAME).read_text())
    sidecar[CHECKSUMS]["rows"] = sidecar[CHECKSUMS]["rows"][:rows]
    (directory / SIDECAR_NAME).write_text(json.dumps(sidecar, indent=2) + "\n")


def sdo_values(frames: list[can.Message], node: int, index: int, *, answers: bool = False) -> list[tuple[int, int]]:
    """(frame position, value) of every expedited SDO transfer of object ``index`` of CANopen node ``node`` among
    ``frames``, read as CiA 301 lays them out: downloads from the client (``answers`` False: the values written)
    or upload answers from the node (True: the values read)."""
    cob_id, command = (0x580, 0x43) if answers else (0x600, 0x23)
    out = []
    for i, m in enumerate(frames):
        d = bytes(m.data)
        if m.arbitration_id == cob_id + node and len(d) == 8 and d[0] & 0xE3 == command and \
                int.from_bytes(d[1:3], "little") == index:
            out.append((i, int.from_bytes(d[4:8 - ((d[0] >> 2) & 3)], "little")))
    return out


def run_session(data: dict[str, Any], source: str, out: Path | None = None) -> tuple[BenchSession, SessionError | None]:
    """The bench session of the first case of configuration ``data`` (named ``source`` in errors), run to its end:
    the session, and the error that stopped it (None when it completed)."""
    from bodebench.bench.connection import plan_link
    from bodebench.bench.events import SessionError
    from bodebench.bench.session import BenchSession
    from bodebench.io.config import parse_config

    case = parse_config(data, source).cases[0]
    session = BenchSession(case, plan_link(case), out)
    try:
        session.run()
    except SessionError as exc:
        return session, exc
    return session, None
