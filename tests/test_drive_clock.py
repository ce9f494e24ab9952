"""A simulated drive on the realtime clock keeps its own time as a drive does: a stall of its process (a busy
bench PC) is caught up tick by tick, so its sample counter stays on the wall clock and the instrument's timeline,
which dates samples by that counter, does not slip (a slip shifts every later phase by f times the slip)."""

from __future__ import annotations

import threading
import time
import uuid

import can

from bodebench.bench.offline import build_plant
from bodebench.drivers.ports import CanPort, Frame
from bodebench.io.config import load_config
from bodebench.sim.controller import ControllerTiming, SimulatedController

RATE_HZ = 1000.0
STALL_S = 0.3


class StallingPort(CanPort):
    """The drive's end of a virtual bus whose process stalls once for STALL_S (its receive call does not return);
    every frame it sends is dated (wall clock) with the drive's tick count at that moment."""

    def __init__(self, bus: can.BusABC, controller: SimulatedController) -> None:
        super().__init__(bus)
        self.controller = controller
        self.stall = threading.Event()
        self.sent: list[tuple[float, int]] = []

    def recv(self, timeout: float) -> list[Frame]:
        if self.stall.is_set():
            self.stall.clear()
            time.sleep(STALL_S)
        return super().recv(timeout)

    def send(self, frame: Frame) -> None:
        super().send(frame)
        self.sent.append((time.perf_counter(), self.controller.tick_count))


def test_a_stalled_drive_catches_up_and_its_counter_keeps_to_the_wall_clock() -> None:
    channel = f"clock-{uuid.uuid4().hex[:8]}"
    case = load_config("configs/sim_can.toml").cases[0]
    assert case.layout is not None and case.plant is not None
    controller = SimulatedController(build_plant(case.plant), case.layout, ControllerTiming(RATE_HZ, clock="realtime"))
    host = can.Bus(interface="virtual", channel=channel)  # the instrument's end: takes the frames off the bus
    port = StallingPort(can.Bus(interface="virtual", channel=channel), controller)
    stop = threading.Event()
    drive = threading.Thread(target=controller.serve, args=(port, stop), daemon=True)
    drive.start()
    try:
        while len(port.sent) < 100:
            time.sleep(0.01)
            while host.recv(0.0) is not None:
                pass
        port.stall.set()
        deadline = time.perf_counter() + STALL_S + 1.0
        while time.perf_counter() < deadline:
            while host.recv(0.0) is not None:
                pass
            time.sleep(0.005)
    finally:
        stop.set()
        drive.join(5)
        port.close()
        host.shutdown()
    t_first, tick_first = port.sent[0]
    # how far the drive's count is behind the wall clock at each frame, in ticks; over the last 0.3 s: the
    # smallest (a loaded machine delays frames, it cannot make the count run ahead)
    lag = [(t - t_first) * RATE_HZ - (tick - tick_first) for t, tick in port.sent]
    tail = [g for (t, _), g in zip(port.sent, lag, strict=True) if t > port.sent[-1][0] - 0.3]
    assert min(tail) < 0.1 * STALL_S * RATE_HZ, f"the drive's count lags the wall clock by {min(tail):.0f} ticks"
