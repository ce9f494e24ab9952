"""What a results directory says about the runs that made it: when, where, with what software, over which link,
and how the bus and the pacing fared (the ``runs`` list of the sidecar; one record per run, a resumed sweep adds
one)."""

from __future__ import annotations

import dataclasses
import math
import platform
import socket
from collections.abc import Sequence
from datetime import UTC, datetime
from importlib import metadata
from typing import Any

from bodebench.bench.session import SessionResult
from bodebench.io.config import CaseConfig

__all__ = ["RunClock", "json_safe", "link_description", "run_record"]


def _version() -> str:
    try:
        return metadata.version("bodebench")
    except metadata.PackageNotFoundError:
        return "unknown"


def json_safe(value: Any) -> Any:
    """``value`` with dataclasses as dicts, tuples as lists and non-finite floats as None (JSON without NaN)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (str, int, bool)):
        return value
    return str(value)


def link_description(case: CaseConfig, direct: bool) -> dict[str, Any]:
    """How the case reached its plant or drive: offline, the simulated drive in-process, or a bus."""
    if case.bench is None:
        return {"kind": "offline", "plant": case.plant.model if case.plant is not None else ""}
    bench = case.bench
    out: dict[str, Any] = {"kind": "in-process simulated drive" if direct else "bus", "transport": bench.transport,
                           "clock": bench.clock, "rate_hz": bench.rate_hz, "timebase": bench.timebase}
    if not direct and bench.transport == "can" and case.can is not None:
        out.update(interface=case.can.interface, channel=case.can.channel or "(the simulator's)",
                   bitrate=case.can.bitrate)
    if not direct and bench.transport == "serial" and case.serial is not None:
        out.update(port=case.serial.port or "(the simulator's pseudo-terminal)", baudrate=case.serial.baudrate,
                   framing=case.serial.framing)
    out["simulated"] = case.simulator is not None
    return out


@dataclasses.dataclass
class RunClock:
    """When a run of a case started (UTC wall clock)."""

    started: datetime = dataclasses.field(default_factory=lambda: datetime.now(UTC))


def run_record(case: CaseConfig, clock: RunClock, *, direct: bool, points: int, resumed: bool,
               result: SessionResult | None, completed: bool, reason: str = "",
               refused: Sequence[tuple[float, str]] = (), plan_notes: Sequence[str] = (),
               drive_start: str = "") -> dict[str, Any]:
    """The record of one run: start, end and duration (s), software, host, link, points in the directory at its
    end, whether it resumed an earlier run, how it ended, and for a bench run the bus counters, the round trip
    (s), the pacing statistics (s) at its end, the sample counters (with the periods discarded for gaps in the
    feedback) and, when the bus log stopped recording early, why (``bus_log_failure``); the frequencies whose points
    were refused, with why (``refused``); what the loader moved in the plan or warned of (``plan``); what the driver
    did and measured to enable the drive (``drive_start``, where it says)."""
    ended = datetime.now(UTC)
    record: dict[str, Any] = {
        "started": clock.started.isoformat(timespec="milliseconds"),
        "ended": ended.isoformat(timespec="milliseconds"),
        "duration_s": round((ended - clock.started).total_seconds(), 3),
        "software": {"name": "bodebench", "version": _version(), "python": platform.python_version()},
        "host": {"name": socket.gethostname(), "platform": platform.platform()},
        "link": link_description(case, direct),
        "points": points,
        "resumed": resumed,
        "completed": completed,
    }
    if reason:
        record["ended_by"] = reason
    if result is not None and result.health is not None:
        health = result.health
        record["bus"] = json_safe(health.bus)
        record["round_trip_s"] = json_safe(health.round_trip_s)
        record["pacing"] = json_safe(health.pacing) if health.pacing is not None else "lockstep clock (no pacing)"
        record["samples"] = {"time_conflicts": health.time_conflicts, "invalid": health.invalid_samples,
                             "missed_replies": health.missed_replies, "counter_anomalies": health.counter_anomalies,
                             "periods_discarded": result.periods_discarded, "stale_setpoint": result.stale_samples}
    if drive_start:
        record["drive_start"] = drive_start
    if plan_notes:
        record["plan"] = list(plan_notes)
    if refused:
        record["refused"] = [{"frequency_hz": f, "reason": why} for f, why in refused]
    if result is not None and result.log_failure:
        record["bus_log_failure"] = result.log_failure
    return record
