"""From a bench config to a link: what the bus worker opens, and the simulated drive behind it if any.

The ``*Link`` objects are picklable recipes called inside the bus worker
(its own process on the realtime clock); each returns (frame port, layout,
resources to close when the worker ends).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

from bodebench.drivers.canopen_link import CanopenDriver, CanopenSetup
from bodebench.drivers.driver import Driver
from bodebench.drivers.layout import Layout
from bodebench.drivers.ports import CanPort, FramePort, SerialPort
from bodebench.io.config import CaseConfig, ConfigError

if TYPE_CHECKING:  # the simulator is imported only where a simulated drive is run
    from bodebench.sim.serve import SimulatorSpec

SLCAN_DEFAULTS = {"sleep_after_open": 0.0}


@dataclass(frozen=True)
class CanLink:
    """A python-can bus; ``simulator``: serve the simulated drive on the same bus from the worker's process."""

    interface: str
    channel: str
    bitrate: int | None
    options: dict[str, Any]
    layout: Layout
    simulator: SimulatorSpec | None = None
    fd: bool = False
    log: str = ""
    """A bus log of every frame the host sends and receives (python-can's Logger; empty: none)."""

    def __call__(self) -> tuple[FramePort, Layout, list[Any]]:
        resources: list[Any] = []
        if self.simulator is not None:
            from bodebench.sim.serve import serve_can

            resources.append(serve_can(self.simulator))
        try:
            port = CanPort.open(self.interface, self.channel, self.bitrate, self.options, fd=self.fd,
                                log=self.log or None)
        except BaseException:
            for r in resources:
                r.close()
            raise
        return port, self.layout, resources


@dataclass(frozen=True)
class CanopenLink:
    """A CiA 402 drive on a python-can bus, driven by ``CanopenDriver``; ``simulator``: serve the simulated CiA 402
    drive on the same bus from the worker's process."""

    interface: str
    channel: str
    bitrate: int | None
    options: dict[str, Any]
    setup: CanopenSetup
    layout: Layout
    simulator: SimulatorSpec | None = None
    log: str = ""
    """A bus log of every frame the host sends and receives, SDO, NMT and heartbeats included (empty: none)."""

    def __call__(self) -> tuple[FramePort, Layout, list[Any]]:
        link = CanLink(self.interface, self.channel, self.bitrate, self.options, self.layout, self.simulator,
                       log=self.log)
        return link()

    def make_driver(self, port: FramePort, layout: Layout) -> Driver:
        """The driver the bus worker uses on ``port``."""
        return CanopenDriver(port, self.setup, layout)


@dataclass(frozen=True)
class SerialLink:
    """A serial line opened with pyserial; a write that stalls is retried for ``send_timeout_s``."""

    port: str
    baudrate: int
    framing: str
    layout: Layout
    send_timeout_s: float = 1.0
    log: str = ""
    """A raw log of every byte written and read (:class:`~bodebench.drivers.ports.ByteLog`; empty: none)."""

    def __call__(self) -> tuple[FramePort, Layout, list[Any]]:
        return (SerialPort.open(self.port, self.baudrate, self.framing, self.layout, self.send_timeout_s,
                                log=self.log or None), self.layout, [])


def stall_budget(case: CaseConfig) -> float:
    """How long (s) a stalled write may be retried: until the host's watchdog (safety.watchdog_s) would stop the
    sweep anyway, and no longer than the drive's own watchdog lets it go without a frame."""
    tables = case.on_bench
    budget = float(tables.safety.watchdog_s)
    return min(budget, tables.layout.drive_watchdog_s) if tables.layout.drive_watchdog_s else budget


@dataclass(frozen=True)
class DirectLink:
    """The simulated drive called directly (lockstep), frames encoded and decoded as on a bus."""

    simulator: SimulatorSpec
    transport: str = "can"

    def __call__(self) -> tuple[FramePort, Layout, list[Any]]:
        from bodebench.sim.serve import ControllerPort

        return ControllerPort(self.simulator.controller(), self.transport), self.simulator.layout, []


@dataclass
class LinkPlan:
    """The recipe for the worker and what the session must close at the end (a simulator process)."""

    open_link: Any
    layout: Layout
    resources: list[Any] = field(default_factory=list)
    where: str = ""

    def close(self) -> None:
        for r in self.resources:
            r.close()


def simulator_spec(case: CaseConfig, *, wire_faults: bool = True) -> SimulatorSpec:
    """The simulated drive of a case: [plant] behind the controller at [bench] rate and clock, with the
    [simulator] jitter, noise and quantization.

    wire_faults: with the configured faults (False: none, for the in-process drive of ``bodebench simulate``)."""
    tables = case.on_bench
    bench, sim, serial, can = tables.bench, case.simulator, case.serial, case.can
    if case.plant is None:
        raise ConfigError(f"{case.source}: plant: missing: the simulated drive needs a [plant] table", "plant")
    from bodebench.sim.controller import ControllerTiming, FeedbackSensing
    from bodebench.sim.loop_config import LoopConfig
    from bodebench.sim.serve import SimulatorSpec

    timing = ControllerTiming(bench.rate_hz, bench.clock, sim.jitter if sim else 0.0,
                              sim.seed if sim else 0, bench.pacing_cpu)
    sensing = FeedbackSensing(sim.noise, sim.quantization, sim.seed, sim.hum, sim.hum_hz) if sim else None
    can_map: dict[str, Any] = {}
    if can is not None:
        can_map = {"interface": can.interface, "channel": can.channel or "bodebench", "bitrate": can.bitrate,
                   "fd": can.fd, "options": dict(can.options)}
    faults = sim.faults if sim is not None and wire_faults else None
    device_faults = sim.canopen if sim is not None and wire_faults and sim.canopen.any else None
    return SimulatorSpec(asdict(case.plant), tables.layout, timing, serial.framing if serial else "binary", can_map,
                         faults if faults is not None and faults.any else None, sensing, case.canopen_setup,
                         device_faults, sim.loop if sim is not None else LoopConfig())


def plan_link(case: CaseConfig, *, direct: bool = False, log: str = "") -> LinkPlan:
    """How the worker reaches the drive of ``case`` (starting the simulated drive where the config has one).

    direct: the simulated drive called in-process without a bus (``bodebench simulate``): its jitter, noise
    and quantization as configured; faults, which need a wire, are refused. log: a file for the host's traffic,
    a python-can log on CAN (its suffix picks the format), a raw byte log on a serial line (none without a bus).
    """
    tables = case.on_bench
    bench, layout, sim, serial = tables.bench, tables.layout, case.simulator, case.serial
    simulated = sim is not None
    if direct:
        if sim is not None and sim.faults.any:
            raise ConfigError(f"{case.source}: simulator.faults: fault injection needs a bus; bodebench simulate runs "
                              "the drive in-process (use bodebench run, or remove [simulator.faults])",
                              "simulator.faults")
        if sim is not None and sim.canopen.any:
            raise ConfigError(f"{case.source}: simulator.canopen: drive faults need a bus; bodebench simulate runs "
                              "the drive in-process (use bodebench run, or remove [simulator.canopen])",
                              "simulator.canopen")
        transport = (f"serial-{serial.framing}" if bench.transport == "serial" and serial
                     else "can-fd" if case.can is not None and case.can.fd else "can")
        return LinkPlan(DirectLink(simulator_spec(case, wire_faults=False), transport), layout,
                        where="in-process")
    if bench.transport == "canopen":
        can = case.can
        assert can is not None and case.canopen_setup is not None  # the loader made sure
        channel = can.channel or "bodebench"
        spec = simulator_spec(case) if simulated else None
        co_link = CanopenLink(can.interface, channel, can.bitrate, dict(can.options), case.canopen_setup, layout,
                              spec, log)
        return LinkPlan(co_link, layout, where=f"CANopen node {case.canopen_setup.node_id} on {can.interface} "
                                            f"channel {channel}")
    if bench.transport == "can":
        can = case.can
        assert can is not None  # the loader made sure: transport "can" needs a [can] table
        options = dict(can.options)
        if can.interface == "slcan":
            options = {**SLCAN_DEFAULTS, **options}
        if simulated and can.interface == "slcan" and not can.channel:
            from bodebench.sim.serve import SimulatorProcess

            proc = SimulatorProcess(simulator_spec(case), "slcan")
            link = CanLink("slcan", proc.path, can.bitrate, options, layout, fd=can.fd, log=log)
            return LinkPlan(link, layout, [proc], where=f"slcan adapter on {proc.path}")
        channel = can.channel or "bodebench"
        spec = None
        if simulated and can.interface != "slcan":
            # served from the bus worker's own process: on the realtime clock the worker's pacing is the drive's
            # clock (a second pacing thread would fight the worker for the interpreter), so it answers each setpoint
            spec = simulator_spec(case)
            spec = replace(spec, timing=replace(spec.timing, clock="lockstep"))
        link = CanLink(can.interface, channel, can.bitrate, options, layout, spec, fd=can.fd, log=log)
        return LinkPlan(link, layout, where=f"{can.interface} channel {channel}")
    assert serial is not None  # the loader made sure: transport "serial" needs a [serial] table
    budget = stall_budget(case)
    if simulated and not serial.port:
        from bodebench.sim.serve import SimulatorProcess

        proc = SimulatorProcess(simulator_spec(case), "serial")
        return LinkPlan(SerialLink(proc.path, serial.baudrate, serial.framing, layout, budget, log), layout, [proc],
                        where=f"serial {proc.path}")
    return LinkPlan(SerialLink(serial.port, serial.baudrate, serial.framing, layout, budget, log), layout,
                    where=f"serial {serial.port}")
