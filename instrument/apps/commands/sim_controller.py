"""``bodebench sim-controller``: the simulated drive served on its own, and the bench configuration that reaches it."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bodebench.io.document import Override

from bodebench.apps.commands.common import _ArgumentError, _load

log = logging.getLogger("bodebench")


def _sim_controller(args: argparse.Namespace) -> int:
    from bodebench.bench.connection import simulator_spec
    from bodebench.io.config import ConfigError
    from bodebench.sim.canopen_device import ServingCanopen
    from bodebench.sim.serve import Serving, serve_can, serve_serial_pty, serve_slcan_pty

    config = _load(args)
    if args.write_config is not None:
        _check_copy_path(Path(args.config), Path(args.write_config))
    case = config.cases[0]
    if case.bench is None or case.simulator is None or case.plant is None:
        raise ConfigError(f"{args.config}: simulator: missing (sim-controller needs [bench], [plant] and "
                          "[simulator])", "simulator")
    bench, layout = case.on_bench.bench, case.on_bench.layout
    spec = simulator_spec(case)
    serving: Serving | ServingCanopen
    # what a bench config needs to reach this drive: the key to set, and whether [simulator] must go (a bench
    # config that keeps it on a CAN bus serves a simulated drive of its own)
    reach: tuple[tuple[str, str], str]
    drop_simulator = False
    if bench.transport == "serial":
        serving, path = serve_serial_pty(spec)
        where = f"serial ({spec.framing} framing) on {path}: set [serial] port = \"{path}\""
        reach = (("serial", "port"), path)
    elif bench.transport == "canopen":
        if case.can is not None and case.can.interface == "slcan":
            raise ConfigError(f"{args.config}: can.interface: the simulated CANopen device is served on a python-can "
                              "bus (virtual, udp_multicast, socketcan, ...), not as an SLCAN adapter",
                              "can.interface")
        serving = serve_can(spec)
        profile = spec.canopen.device_profile if spec.canopen else None
        where = (f"{profile.name if profile else 'CANopen'} {profile.device if profile else 'device'}, CANopen node "
                 f"{spec.canopen.node_id if spec.canopen else '?'}, on python-can "
                 f"{spec.can['interface']} channel {spec.can['channel']}")
        reach, drop_simulator = (("can", "channel"), str(spec.can["channel"])), True
    elif case.can is not None and case.can.interface == "slcan":
        serving, path = serve_slcan_pty(spec)
        where = f"SLCAN adapter on {path}: set [can] channel = \"{path}\""
        reach = (("can", "channel"), path)
    else:
        serving = serve_can(spec)
        where = f"python-can {spec.can['interface']} channel {spec.can['channel']}"
        reach, drop_simulator = (("can", "channel"), str(spec.can["channel"])), True
    if args.write_config is not None:
        try:
            written = _write_bench_copy(args, reach, drop_simulator)
        except BaseException:
            serving.close()
            raise
        where += f"; a bench config for it: {written} (bodebench run {written} --out DIR)"
    serving_started = time.monotonic()

    def report(text: str) -> None:  # each change of the drive's state, as the drive saw it
        print(f"{time.monotonic() - serving_started:10.3f} s  drive {text}", flush=True)

    serving.controller.on_event = report
    if bench.transport == "canopen":  # a CANopen device watches the host's heartbeat once the host writes 0x1016
        watchdog = "; it watches the host's heartbeat where the host sets its 0x1016 (canopen.host_heartbeat_ms)"
    else:
        watchdog = f"; watchdog {layout.drive_watchdog_s:g} s" if layout.drive_watchdog_s else "; no watchdog"
    print(f"simulated {case.plant.model} drive, {bench.clock} clock at {bench.rate_hz:g} Hz{watchdog}, "
          f"listening: {where}", flush=True)
    try:
        while not serving.stop.wait(0.5):
            if args.seconds and time.monotonic() - serving_started > args.seconds:
                break
    except KeyboardInterrupt:
        pass
    finally:
        serving.close()
    c = serving.controller
    print(f"stopped after {c.tick_count} control periods; last setpoint {c.applied:g}, "
          f"{'enabled' if c.enabled else 'disabled'}")
    return 0


def _check_copy_path(config: Path, copy: Path) -> None:
    """--write-config: a file in an existing directory, not the configuration itself."""
    if copy.is_dir():
        raise _ArgumentError(f"--write-config {copy}: is a directory")
    if not copy.parent.is_dir():
        raise _ArgumentError(f"--write-config {copy}: no directory {copy.parent}")
    if copy.exists() and copy.resolve() == config.resolve():
        raise _ArgumentError(f"--write-config {copy}: is the configuration itself (write the copy elsewhere)")


def _write_bench_copy(args: argparse.Namespace, reach: tuple[tuple[str, str], str], drop_simulator: bool) -> Path:
    """Write --write-config: the configuration file with its --set overrides, the key that reaches the served
    drive (``reach``: key parts and value) and, on a CAN bus, without [simulator]; relative file names in it
    (frames.dbc, canopen.eds) made absolute when the copy goes to another directory. The copy is validated;
    raises ResultsError when it cannot be written."""
    from bodebench.io.config import SIMULATED_EDS, ConfigError, load_config, read_document
    from bodebench.io.document import Override, OverrideError, apply_overrides, edited_copy
    from bodebench.io.results import ResultsError, atomic_write_text

    source, target = Path(args.config), Path(args.write_config)
    overrides: list[Override] = list(args.set or ())
    document, _ = apply_overrides(read_document(source), overrides)
    if source.resolve().parent != target.resolve().parent:
        tables: list[tuple[tuple[str, ...], dict[str, Any]]] = [((), document)]
        cases = document.get("cases")
        if isinstance(cases, dict):
            tables += [(("cases", str(name)), body) for name, body in cases.items() if isinstance(body, dict)]
        for prefix, body in tables:
            for table, key in (("frames", "dbc"), ("canopen", "eds")):
                sub = body.get(table)
                name = sub.get(key) if isinstance(sub, dict) else None
                if isinstance(name, str) and name and not Path(name).is_absolute():
                    overrides.append(Override((*prefix, table, key), str((source.parent / name).resolve())))
    parts, value = reach
    current = document.get(parts[0], {})
    if not isinstance(current, dict) or current.get(parts[1]) != value:
        overrides.append(Override(parts, value))
    canopen = document.get("canopen")
    if drop_simulator and isinstance(canopen, dict) and not canopen.get("eds"):
        profile = str(canopen.get("profile", "402"))
        if profile in SIMULATED_EDS:  # the [simulator] brought it
            overrides.append(Override(("canopen", "eds"), str(SIMULATED_EDS[profile])))
    header = (f"written by bodebench sim-controller: {source}, {'.'.join(parts)} set to {value}, where it serves "
              "the simulated drive" + (" ([simulator] left out: the drive is the one served)" if drop_simulator
                                       else ""))
    try:
        text = edited_copy(source.read_text(encoding="utf-8"), overrides,
                           ("simulator",) if drop_simulator else (), header)
    except (OverrideError, ValueError) as exc:
        raise ResultsError(f"--write-config {target}: {exc}") from None
    try:
        atomic_write_text(target, text)
    except OSError as exc:
        raise ResultsError(f"--write-config {target}: cannot write: {exc.strerror or exc}") from None
    try:
        load_config(target)
    except ConfigError as exc:
        raise ResultsError(f"--write-config {target}: the copy does not validate: {exc}") from None
    return target
