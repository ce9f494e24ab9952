"""Faults on the simulated chain: what the measurement does for each (docs/faults.md).

Every case runs the whole chain (python-can's virtual bus or a serial pseudo-terminal) against the simulated
drive with the fault injected; a completed sweep must agree with the fault-free offline run of the same config.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_bench_e2e import SERIAL_FRAMES, compare, config

from bodebench.bench.connection import plan_link
from bodebench.bench.events import BusStatus, SessionError
from bodebench.bench.session import BenchSession
from bodebench.io.config import parse_config


def run(data: dict[str, Any]) -> tuple[BenchSession, BusStatus | None, SessionError | None]:
    case = parse_config(data, "faults.toml").cases[0]
    last: dict[str, BusStatus] = {}
    session = BenchSession(case, plan_link(case), None,
                           lambda e: last.__setitem__("h", e) if isinstance(e, BusStatus) else None)
    error = None
    try:
        session.run()
    except SessionError as exc:
        error = exc
    return session, last.get("h"), error


# Lost samples are noise (the signal is interpolated across the gap): measure the first harmonic to 0.05 %, as one
# would on a lossy link; to 0.01 % of itself a 3rd harmonic 26 dB down would take thousands of periods of it
FIRST = {"harmonics": [1], "tolerance_percent": 0.05}


def can_config(channel: str, faults: dict[str, Any], **tables: Any) -> dict[str, Any]:
    tables.setdefault("analysis", FIRST)
    return config(can={"channel": channel}, simulator={"faults": {"seed": 5, **faults}}, **tables)


def serial_config(faults: dict[str, Any], **tables: Any) -> dict[str, Any]:
    return config(bench={"transport": "serial"}, can=None, serial={"framing": "binary"}, frames=SERIAL_FRAMES,
                  simulator={"faults": {"seed": 5, **faults}}, analysis=FIRST, **tables)


@pytest.fixture(scope="module")
def offline_can():
    case = parse_config(config(analysis=FIRST), "faults.toml").cases[0]
    session = BenchSession(case, plan_link(case, direct=True))
    session.run()
    return session.response


@pytest.fixture(scope="module")
def offline_serial():
    case = parse_config(serial_config({}), "faults.toml").cases[0]
    session = BenchSession(case, plan_link(case, direct=True))
    session.run()
    return session.response


@pytest.mark.slow
@pytest.mark.parametrize("name, faults, counted", [
    ("drop 1 %", {"drop": 0.01}, lambda h: h.bus.lost_samples + h.bus.incomplete_samples),
    # a tenth of the samples missing is heavy noise: measured to 0.2 % (0.017 dB), still inside the comparison
    ("drop 10 %", {"drop": 0.10, "tolerance_percent": 0.2}, lambda h: h.bus.lost_samples + h.bus.incomplete_samples),
    ("duplicate 5 %", {"duplicate": 0.05}, lambda h: h.bus.duplicates),
    ("reorder 5 %", {"reorder": 0.05}, lambda h: h.missed_replies),
    ("error frames 5 %", {"error_frames": 0.05}, lambda h: h.bus.errors),
    ("delayed replies", {"delay_s": 0.0005, "delay_jitter_s": 0.0005}, lambda h: 1),
])
def test_frame_faults_on_can_complete_with_correct_figures(offline_can, name: str, faults: dict[str, Any],
                                                           counted) -> None:
    channel = "faults-" + name.replace(" ", "-").replace("%", "pct")
    faults = dict(faults)
    tolerance = faults.pop("tolerance_percent", FIRST["tolerance_percent"])
    session, health, error = run(can_config(channel, faults, analysis={**FIRST, "tolerance_percent": tolerance}))
    assert error is None, f"{name}: {error}"
    compare(session.response, offline_can, 0.05, 0.2)
    assert counted(health.health) > 0, f"{name}: not counted in {health.health}"


@pytest.mark.slow
def test_random_bytes_on_the_serial_line_are_survived(offline_serial) -> None:
    session, health, error = run(serial_config({"garbage": 0.1}))
    assert error is None
    compare(session.response, offline_serial, 0.05, 0.2)
    assert health.health.bus.resyncs > 0  # runs of garbage between frames, counted


@pytest.mark.slow
def test_a_jumping_counter_is_realigned(offline_can) -> None:
    session, health, error = run(can_config("faults-jump", {"counter_jump_at": 1500, "counter_jump_by": 300}))
    assert error is None
    compare(session.response, offline_can, 0.05, 0.2)
    assert health.health.counter_anomalies >= 3


@pytest.mark.slow
def test_nan_and_infinity_in_float_frames_are_dropped(offline_can) -> None:
    session, health, error = run(can_config("faults-nan", {"nan": 0.01}))
    assert error is None
    compare(session.response, offline_can, 0.05, 0.2)
    assert health.health.invalid_samples > 0


@pytest.mark.parametrize("name, faults, kind", [
    ("stuck counter", {"counter_stuck_after": 1500}, "watchdog"),
    ("drive stops answering", {"stop_after_s": 1.5}, "watchdog"),
    ("bus-off", {"bus_off_after_s": 1.5}, "watchdog"),
    ("sensor out of range", {"out_of_range_after_s": 1.5}, "feedback_limit"),
    ("drive disables itself and goes on answering", {"disable_after_s": 1.5}, "no_response"),
    ("every feedback value NaN", {"nan": 1.0}, "watchdog"),  # frames that carry nothing valid feed no watchdog
])
def test_faults_that_end_the_sweep_leave_the_drive_safe(name: str, faults: dict[str, Any], kind: str) -> None:
    from helpers import BusRecorder

    channel = "faults-" + name.replace(" ", "-")
    recorder = BusRecorder(channel)
    session, _, error = run(can_config(channel, faults, safety={"watchdog_s": 0.3,
                                                                 "feedback_limits": {"position": [-1.0, 1.0]}}))
    value, disabled = recorder.close()
    # a drive disabled unreported is caught by its flat feedback, or, on a machine so busy that 0.3 s passes without a
    # valid frame first, by the host's watchdog: either way the sweep ends and the drive is left safe
    assert error is not None and (error.kind == kind or kind == "no_response" and error.kind == "watchdog"), name
    assert value == 0.0 and disabled
    # what was measured before the fault is kept, whole
    assert all(p.converged for p in session.response.points)
    assert np.all(np.isfinite([p.gain for p in session.response.points]))


def test_a_drive_that_stops_following_is_never_a_point_and_the_run_keeps_its_record(tmp_path: Path) -> None:
    """Disabled unreported before the first point ends: valid frames of a plant at rest. No point is written, the
    sweep ends saying why, and the results directory holds the run's record with the bus counters and the reason."""
    from bodebench.bench.procedure import SweepProcedure
    from bodebench.io.results import load_response

    data = can_config("faults-disabled-record", {"disable_after_s": 0.3})
    out = tmp_path / "out"
    with pytest.raises(SessionError) as raised:
        SweepProcedure(parse_config(data, "faults.toml"), out).run()
    assert raised.value.kind == "no_response"
    assert "not following the setpoint" in str(raised.value)
    assert len(load_response(out)) == 0
    run = json.loads((out / "response.json").read_text())["runs"][-1]
    assert run["completed"] is False and run["points"] == 0
    assert "not following the setpoint" in run["ended_by"] and run["refused"][0]["frequency_hz"] > 0
    assert run["bus"]["frames_in"] > 0 if "frames_in" in run["bus"] else run["bus"]


@pytest.mark.slow
@pytest.mark.parametrize("name, faults, kind", [
    ("sensor out of range", {"out_of_range_after_s": 1.5}, "feedback_limit"),
    ("drive disables itself and goes on answering", {"disable_after_s": 1.5}, "no_response"),
    ("every feedback value NaN", {"nan": 1.0}, "watchdog"),
])
def test_on_the_realtime_clock_garbage_feedback_ends_the_sweep_with_the_drive_safe(name: str, faults: dict[str, Any],
                                                                                   kind: str) -> None:
    """The same faults with the bus worker pacing setpoints in real time, in its own process: the sweep ends, the
    drive is seen zeroed and disabled on the bus."""
    from helpers import BusRecorder

    channel = "faults-rt-" + name.replace(" ", "-")
    recorder = BusRecorder(channel)
    data = can_config(channel, faults, safety={"watchdog_s": 0.3, "feedback_limits": {"position": [-1.0, 1.0]}})
    data["bench"] = {**data["bench"], "clock": "realtime", "worker": "thread"}
    session, _, error = run(data)
    value, disabled = recorder.close()
    assert error is not None and (error.kind == kind or kind == "no_response" and error.kind == "watchdog"), name
    assert value == 0.0 and disabled
    assert all(p.converged for p in session.response.points)


def test_garbage_feedback_trips_the_watchdog_within_its_time_of_setpoints() -> None:
    """Every feedback value NaN from the start: the lockstep drive answers every setpoint with nothing valid. The
    watchdog (0.3 s) leaves out only the time no setpoint was asked for, so the sweep ends after about 0.3 s of
    setpoints: far fewer replies than the lockstep chain carries in a second (it carries at most some 10,000
    frames a second on this kind of machine), not the minute of them a watchdog fed at every pause would allow."""
    _, health, error = run(can_config("faults-nan-count", {"nan": 1.0}, safety={"watchdog_s": 0.3}))
    assert error is not None and error.kind == "watchdog"
    assert health is not None and 0 < health.health.invalid_samples < 10_000
    # the trip says what the silence held: the setpoints were answered, each reply dropped as invalid
    said = re.search(r"\((\d+) setpoints sent and \d+ frames received on the bus in that time; dropped: (\d+) "
                     r"samples invalid", str(error))
    assert said is not None, str(error)
    assert int(said.group(2)) >= int(said.group(1)) > 0


def test_a_stuck_counter_trip_says_its_replies_were_dropped_as_repeats() -> None:
    """A counter that stops advancing: the drive answers every setpoint with a counter already seen, so the trip
    counts as many frames as setpoints and says where they went (repeats, or replies that came too late to
    count), not a drive that said nothing."""
    _, _, error = run(can_config("faults-stuck-said", {"counter_stuck_after": 1500}, safety={"watchdog_s": 0.3}))
    assert error is not None and error.kind == "watchdog"
    said = re.search(r"\((\d+) setpoints sent and (\d+) frames received on the bus in that time; dropped: (.*)\)",
                     str(error))
    assert said is not None, str(error)
    assert int(said.group(2)) >= int(said.group(1)) > 0, str(error)  # the drive answered every setpoint
    assert said.group(3) != "none", str(error)  # and the trip says where its answers went
