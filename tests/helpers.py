"""Helpers shared by the test modules (imported as ``helpers``: pytest puts tests/ on sys.path)."""

from __future__ import annotations

import threading
from pathlib import Path

import can

from bodebench.drivers.layout import default_layout


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
