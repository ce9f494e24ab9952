"""A drive written from drivers/PROTOCOL.md alone, measured through bodebench's public path.

The drive below imports nothing of bodebench: it encodes and decodes its frames with ``struct`` from the layout the
configuration declares (section 2), proves its feedback frames with CRC-8/SAE-J1850 (section 6), and runs a linear
plant, discretised exactly (zero-order hold, scipy's ``cont2discrete``), on python-can's virtual bus in lockstep: each
setpoint frame advances one control period h = 1 / rate_hz. It implements both orders of the two steps of a period:

- "apply then sample" (the contract of section 7): the setpoint of period n is held over the period, then the
  sensors are sampled; feedback counter n + 1 carries that sample and the echo of the setpoint applied;
- "sample then apply" (common firmware): the state is sampled first (before this setpoint acted), then the setpoint
  is applied; the echo is the setpoint that acted on the sample sent (the previous one).

bodebench's session (its [frames] and [can] tables only, no [plant] or [simulator]) talks to that drive on the same
virtual channel. Section 7's statements are checked against G_d(exp(j w h)) computed here:

- single channel, contract order: G_d exactly (within the point's interval);
- single channel, sample-then-apply: one period later in phase, G_d exp(-j w h), and not G_d;
- two-channel mode (position over setpoint_echo): G_d exp(+j w h) for both orders, which therefore agree.
"""

from __future__ import annotations

import cmath
import math
import struct
import threading
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from scipy import signal

from bodebench.analysis.reanalyse import reanalyse
from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import parse_config
from bodebench.io.results import CSV_NAME, load_response, save_response

APPLY_THEN_SAMPLE = "apply then sample"
SAMPLE_THEN_APPLY = "sample then apply"

SETPOINT_ID, POSITION_ID, ECHO_ID, COMMAND_ID = 0x201, 0x181, 0x182, 0x010
ENABLE, DISABLE = b"\x01", b"\x00"
TOLERANCE_PERCENT = 0.01
AMPLITUDE = 0.01

# the layout this drive speaks, as the configuration declares it (PROTOCOL.md sections 2 and 6)
FRAMES: dict[str, Any] = {
    "setpoint": {"id": SETPOINT_ID, "signals": [{"name": "setpoint", "byte": 0, "type": "float32"},
                                                {"name": "counter", "byte": 4, "type": "uint16"}]},
    "feedback": [
        {"id": POSITION_ID, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                        {"name": "counter", "byte": 4, "type": "uint16"},
                                        {"name": "crc", "byte": 6, "type": "uint8"}]},
        {"id": ECHO_ID, "signals": [{"name": "setpoint_echo", "byte": 0, "type": "float32"},
                                    {"name": "counter", "byte": 4, "type": "uint16"},
                                    {"name": "crc", "byte": 6, "type": "uint8"}]},
    ],
    "enable": {"id": COMMAND_ID, "data": [1]},
    "disable": {"id": COMMAND_ID, "data": [0]},
}


def crc8_sae_j1850(data: bytes) -> int:
    """CRC-8/SAE-J1850: polynomial 0x1D, initial value 0xFF, no reflection, final XOR 0xFF (section 6)."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def feedback_payload(value: float, counter: int) -> bytes:
    """float32 little-endian at byte 0, uint16 counter at byte 4, CRC-8 of those six bytes at byte 6."""
    body = struct.pack("<fH", value, counter % 0x10000)
    return body + bytes([crc8_sae_j1850(body)])


# ------------------------------------------------------------------------------------------------------- plants


@dataclass(frozen=True)
class Plant:
    """A continuous transfer function G(s) = num(s) / den(s) between the drive's output stage and its sensor."""

    name: str
    num: tuple[float, ...]
    den: tuple[float, ...]

    def discrete(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Zero-order-hold state space (Ad, Bd, Cd, Dd) at period h."""
        a, b, c, d = signal.tf2ss(self.num, self.den)
        ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), h, method="zoh")
        return ad, bd, cd, dd

    def g_d(self, frequency_hz: float, h: float) -> complex:
        """G_d(exp(j w h)) from scipy's ZOH discretisation of the transfer function (computed apart from the
        state space the drive runs)."""
        num_d, den_d, _ = signal.cont2discrete((list(self.num), list(self.den)), h, method="zoh")
        z = cmath.exp(2j * math.pi * frequency_hz * h)
        return complex(np.polyval(np.ravel(num_d), z) / np.polyval(np.ravel(den_d), z))


LAG = Plant("lag", (2.0,), (0.02, 1.0))  # G(s) = 2 / (0.02 s + 1)
WN, ZETA = 2 * math.pi * 30.0, 0.5
SECOND_ORDER = Plant("second-order", (WN**2,), (1.0, 2 * ZETA * WN, WN**2))  # 30 Hz, damping ratio 0.5


# -------------------------------------------------------------------------------------------------------- drive


@dataclass
class DriveRecord:
    """What the drive saw, for the checks after a sweep."""

    setpoints: int = 0
    enables: int = 0
    disables: int = 0
    ignored: int = 0
    last_received: float = math.nan
    enabled: bool = False
    errors: list[str] = field(default_factory=list)


class IndependentDrive:
    """A lockstep drive on a virtual CAN channel: one control period per setpoint frame, answered with the feedback
    frames of the setpoint's counter + 1."""

    def __init__(self, channel: str, rate_hz: float, plant: Plant, order: str) -> None:
        assert order in (APPLY_THEN_SAMPLE, SAMPLE_THEN_APPLY)
        self.order = order
        self.ad, self.bd, self.cd, self.dd = plant.discrete(1.0 / rate_hz)
        assert not np.any(self.dd), "a sampled plant with direct feedthrough is not what this drive models"
        self.x = np.zeros((self.ad.shape[0], 1))
        self.previous = 0.0  # sample then apply: the setpoint that acted on the state about to be sampled
        self.record = DriveRecord()
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, name=f"independent drive {channel}", daemon=True)

    def _output(self) -> float:
        return float((self.cd @ self.x)[0, 0])

    def _step(self, u: float) -> None:
        self.x = self.ad @ self.x + self.bd * u

    def period(self, received: float) -> tuple[float, float]:
        """One control period with the setpoint ``received``: (position sample, echo) for the next counter."""
        u = received if self.record.enabled else 0.0  # disabled: zero on the output stage
        if self.order == APPLY_THEN_SAMPLE:
            self._step(u)  # held over the whole period ...
            return self._output(), u  # ... then sampled; the echo is the setpoint applied over that period
        position, echo = self._output(), self.previous  # sampled before this setpoint acts
        self._step(u)
        self.previous = u
        return position, echo

    def _handle(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        if msg.is_extended_id or msg.is_remote_frame:
            self.record.ignored += 1
        elif msg.arbitration_id == COMMAND_ID and data in (ENABLE, DISABLE):
            self.record.enabled = data == ENABLE
            self.record.enables += data == ENABLE
            self.record.disables += data == DISABLE
        elif msg.arbitration_id == SETPOINT_ID and len(data) == 6:
            value, counter = struct.unpack("<fH", data)
            if not math.isfinite(value):
                self.record.errors.append(f"setpoint {value!r} with counter {counter}")
                return
            self.record.setpoints += 1
            self.record.last_received = value
            position, echo = self.period(value)
            for fid, v in ((POSITION_ID, position), (ECHO_ID, echo)):
                self.bus.send(can.Message(arbitration_id=fid, data=feedback_payload(v, counter + 1),
                                          is_extended_id=False))
        else:
            self.record.ignored += 1

    def _serve(self) -> None:
        try:
            while not self.stop.is_set():
                msg = self.bus.recv(0.02)
                if msg is not None:
                    self._handle(msg)
        except Exception as exc:  # reported by the test, not lost in the thread
            self.record.errors.append(repr(exc))


@contextmanager
def drive_on(channel: str, rate_hz: float, plant: Plant, order: str) -> Iterator[IndependentDrive]:
    """The drive serving on ``channel`` while the block runs; stopped, joined and its bus shut down after it."""
    drive = IndependentDrive(channel, rate_hz, plant, order)
    drive.thread.start()
    try:
        yield drive
    finally:
        drive.stop.set()
        drive.thread.join(5.0)
        drive.bus.shutdown()
    assert not drive.thread.is_alive(), "the drive thread did not stop"  # only when the block itself passed


# ------------------------------------------------------------------------------------------------------ helpers


def host_config(channel: str, rate_hz: float, freqs: list[float], reference: bool) -> dict[str, Any]:
    """A real drive's configuration: no [plant], no [simulator]; the bus worker in this process (a thread), where
    python-can's virtual channel reaches the drive's thread."""
    bench: dict[str, Any] = {"transport": "can", "rate_hz": rate_hz, "clock": "lockstep", "timebase": "counter",
                             "worker": "thread"}
    if reference:
        bench["reference_channel"] = "setpoint_echo"
    return {
        "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": freqs},
        "analysis": {"harmonics": [1], "tolerance_percent": TOLERANCE_PERCENT},
        "bench": bench,
        "can": {"interface": "virtual", "channel": channel},
        "frames": FRAMES,
        "safety": {"max_amplitude": 2 * AMPLITUDE, "watchdog_s": 5.0},
    }


@dataclass(frozen=True)
class Measured:
    frequency_hz: float
    value: complex
    uncertainty: float
    converged: bool


def sweep(tmp_path: Path, rate_hz: float, plant: Plant, freqs: list[float], order: str,
          reference: bool) -> tuple[list[Measured], DriveRecord]:
    channel = f"independent-{uuid.uuid4().hex[:8]}"
    config = parse_config(host_config(channel, rate_hz, freqs, reference), "independent.toml")
    case = config.cases[0]
    assert case.plant is None  # bodebench starts no drive of its own: it measures ours
    out = tmp_path / "out"
    with drive_on(channel, rate_hz, plant, order) as drive:
        outcome = SweepProcedure(config, out).run()[0]
    assert outcome.session is not None and not outcome.session.refused
    assert not drive.record.errors, drive.record.errors
    measured = [Measured(p.frequency_hz, complex(p.p, p.q), p.uncertainty, p.converged) for p in load_response(out)]
    assert [m.frequency_hz for m in measured] == freqs
    return measured, drive.record


def relative_errors(measured: list[Measured], expected: dict[float, complex]) -> str:
    """Each point's relative distance from ``expected`` and its stated uncertainty, relative too (for messages)."""
    parts = []
    for m in measured:
        z = expected[m.frequency_hz]
        parts.append(f"{m.frequency_hz:g} Hz: {abs(m.value - z) / abs(z):.2e} (stated {m.uncertainty / abs(z):.1e})")
    return ", ".join(parts)


# (plant, rate): the lag at 2 kHz (one period of phase is 0.54 deg at 3 Hz, 10.8 deg at 60 Hz) and a second-order
# system at 500 Hz (one period is 43.2 deg at 60 Hz)
BENCHES = [pytest.param(LAG, 2000.0, [3.0, 17.0, 60.0], id="lag-2kHz"),
           pytest.param(SECOND_ORDER, 500.0, [7.0, 30.0, 60.0], id="second-order-500Hz")]


# --------------------------------------------------------------------------------------------------- the frames


def test_the_drive_encodes_the_documents_examples() -> None:
    assert crc8_sae_j1850(b"123456789") == 0x4B  # section 6's check value
    # section 6: feedback 0x181, position -0.25, counter 258
    assert feedback_payload(-0.25, 258) == bytes.fromhex("000080be0201a7")
    # section 2: setpoint 1.5 with counter 258
    assert struct.unpack("<fH", bytes.fromhex("0000c03f0201")) == (1.5, 258)


def test_the_two_step_orders_differ_by_one_period_on_the_same_plant() -> None:
    """The drive's own arithmetic, off the bus: sample-then-apply sends at counter c what apply-then-sample sent at
    c - 1, and its echo is one counter later too."""
    a = IndependentDrive(f"unused-{uuid.uuid4().hex[:8]}", 1000.0, SECOND_ORDER, APPLY_THEN_SAMPLE)
    b = IndependentDrive(f"unused-{uuid.uuid4().hex[:8]}", 1000.0, SECOND_ORDER, SAMPLE_THEN_APPLY)
    try:
        a.record.enabled = b.record.enabled = True
        u = [math.sin(0.3 * n) for n in range(50)]
        pa, ea = map(list, zip(*(a.period(v) for v in u), strict=True))
        pb, eb = map(list, zip(*(b.period(v) for v in u), strict=True))
        assert pb[1:] == pa[:-1] and eb[1:] == ea[:-1] and pb[0] == eb[0] == 0.0
        assert ea == u  # the contract's echo: the setpoint applied over the period just ended
        a.record.enabled = False
        assert a.period(1.0)[1] == 0.0  # disabled: zero applied, echoed as 0
    finally:
        a.bus.shutdown()
        b.bus.shutdown()


# --------------------------------------------------------------------------------------------------- the sweeps


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "rate_hz", "freqs"), BENCHES)
def test_single_channel_the_contract_drive_measures_g_d_and_sample_then_apply_one_period_later(
        tmp_path: Path, plant: Plant, rate_hz: float, freqs: list[float]) -> None:
    h = 1.0 / rate_hz
    tol = TOLERANCE_PERCENT / 100
    expected = {f: AMPLITUDE * plant.g_d(f, h) for f in freqs}
    later = {f: expected[f] * cmath.exp(-2j * math.pi * f * h) for f in freqs}

    contract, record = sweep(tmp_path / "a", rate_hz, plant, freqs, APPLY_THEN_SAMPLE, reference=False)
    assert record.enables >= 1 and record.disables >= 1 and not record.enabled and record.last_received == 0.0
    for m in contract:
        z = expected[m.frequency_hz]
        assert m.converged and abs(m.value - z) <= max(m.uncertainty, tol * abs(z)), relative_errors(contract, expected)

    firmware, _ = sweep(tmp_path / "b", rate_hz, plant, freqs, SAMPLE_THEN_APPLY, reference=False)
    for m in firmware:
        z, g = later[m.frequency_hz], expected[m.frequency_hz]
        assert m.converged and abs(m.value - z) <= max(m.uncertainty, tol * abs(z)), relative_errors(firmware, later)
        # one period of phase is far more than the tolerance at every frequency here: the convention matters
        assert abs(1 - cmath.exp(-2j * math.pi * m.frequency_hz * h)) > 10 * tol
        assert abs(m.value - g) > max(m.uncertainty, tol * abs(g)), relative_errors(firmware, expected)


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "rate_hz", "freqs"), BENCHES)
def test_two_channel_mode_measures_one_period_ahead_whichever_the_order(
        tmp_path: Path, plant: Plant, rate_hz: float, freqs: list[float]) -> None:
    h = 1.0 / rate_hz
    tol = TOLERANCE_PERCENT / 100
    ahead = {f: AMPLITUDE * plant.g_d(f, h) * cmath.exp(2j * math.pi * f * h) for f in freqs}
    results: dict[str, list[Measured]] = {}
    for order in (APPLY_THEN_SAMPLE, SAMPLE_THEN_APPLY):
        measured, _ = sweep(tmp_path / order.replace(" ", "-"), rate_hz, plant, freqs, order, reference=True)
        for m in measured:
            z = ahead[m.frequency_hz]
            assert m.converged and abs(m.value - z) <= max(m.uncertainty, tol * abs(z)), \
                f"{order}: {relative_errors(measured, ahead)}"
        results[order] = measured
    for a, b in zip(results[APPLY_THEN_SAMPLE], results[SAMPLE_THEN_APPLY], strict=True):
        assert abs(a.value - b.value) <= max(a.uncertainty, tol * abs(a.value)) + max(b.uncertainty,
                                                                                    tol * abs(b.value))


# ------------------------------------------------------------------------------------ a setpoint in coarse counts

STEP = AMPLITUDE / 20  # the setpoint frame's step: the sine spans 20 of them


class CountingDrive(IndependentDrive):
    """The contract drive, but its setpoint frame carries a signed 16-bit count of ``STEP``: it applies the count
    times STEP, the staircase the frame leaves of the host's sine."""

    def _handle(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        if msg.arbitration_id == SETPOINT_ID and len(data) == 4:
            count, counter = struct.unpack("<hH", data)
            self.record.setpoints += 1
            self.record.last_received = count * STEP
            position, echo = self.period(count * STEP)
            for fid, v in ((POSITION_ID, position), (ECHO_ID, echo)):
                self.bus.send(can.Message(arbitration_id=fid, data=feedback_payload(v, counter + 1),
                                          is_extended_id=False))
        else:
            super()._handle(msg)


@pytest.mark.slow
def test_a_sine_in_coarse_counts_is_measured_against_the_staircase_the_drive_was_given(tmp_path: Path) -> None:
    """The setpoint in counts of a twentieth of the amplitude, on whole grids of 500 and 100 ticks a period: the
    frames round the sine the same way every period, which moves the excitation's fundamental by about 0.3 %, 30
    times the tolerance. The point is taken against the staircase the drive was given, so it reads G_d within its
    tolerance, as a drive with a fine setpoint does; the staircase's fundamental is computed here apart, from the
    counts the drive received."""
    rate_hz, freqs, h = 2000.0, [4.0, 20.0], 1.0 / 2000.0
    tol = TOLERANCE_PERCENT / 100
    channel = f"independent-{uuid.uuid4().hex[:8]}"
    data = host_config(channel, rate_hz, freqs, reference=False)
    data["frames"] = {**FRAMES, "setpoint": {"id": SETPOINT_ID, "signals": [
        {"name": "setpoint", "byte": 0, "type": "int16", "scale": STEP},
        {"name": "counter", "byte": 2, "type": "uint16"}]}}
    config = parse_config(data, "counts.toml")
    out = tmp_path / "out"
    drive = CountingDrive(channel, rate_hz, LAG, APPLY_THEN_SAMPLE)
    drive.thread.start()
    try:
        SweepProcedure(config, out).run()
    finally:
        drive.stop.set()
        drive.thread.join(5.0)
        drive.bus.shutdown()
    assert not drive.record.errors and not drive.record.enabled and drive.record.last_received == 0.0
    for p in load_response(out):
        f = p.frequency_hz
        ticks = round(rate_hz / f)
        theta = 2 * np.pi * np.arange(ticks) / ticks
        staircase = np.round(AMPLITUDE * np.sin(theta) / STEP) * STEP
        moved = complex(np.sum(staircase * np.exp(-1j * theta)) / np.sum(AMPLITUDE * np.sin(theta)
                                                                             * np.exp(-1j * theta)))
        assert abs(moved - 1) > 10 * tol  # the rounding matters here
        z = AMPLITUDE * LAG.g_d(f, h)
        value = complex(p.p, p.q)
        assert p.converged and abs(value - z) <= tol * abs(z), (f, abs(value - z) / abs(z))
        assert abs(value - z * moved) > tol * abs(z)  # what the sine's fundamental would have given
    # analysed again from its samples, the run gives its CSV byte for byte, and a looser tolerance G_d within it
    save_response(reanalyse(out).response, tmp_path / "again")
    assert (tmp_path / "again" / CSV_NAME).read_bytes() == (out / CSV_NAME).read_bytes()
    for p in reanalyse(out, tolerance_percent=4 * TOLERANCE_PERCENT).response:
        z = AMPLITUDE * LAG.g_d(p.frequency_hz, h)
        assert p.converged and p.periods > 0 and abs(complex(p.p, p.q) - z) <= 4 * tol * abs(z)
