"""Gaps in the feedback stream: a period a gap touches is discarded, counted and reported, never integrated across.

A sampled sine of known amplitude and phase, with samples cut out, must give the exact coefficient from its whole
periods, and the count of discarded periods must be the number of periods the gap touched; a stream with gaps in
most periods fails with a message, at the discarded period from which no later period could bring the share back
within ``max_discarded_percent`` of the period budget. On the virtual CAN bus the simulated drive stalls (answers
nothing for a while, its clock going on): the sweep's gains stay within their stated uncertainty of the exact
response, and the samples' replay discards the same periods.
"""

from __future__ import annotations

import cmath
import dataclasses
import json
import math
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import signal

from bodebench.analysis.reanalyse import reanalyse
from bodebench.bench.procedure import SweepProcedure
from bodebench.core.autointegration import Autointegrator, GapsError, discard_limit, too_many_discarded
from bodebench.core.fourier import PeriodIntegrator
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.results import load_response, save_response
from bodebench.io.tables import AnalysisConfig

F = 2.0  # Hz
K = 64  # samples a period (a power of two: the sample times in periods are exact binary fractions)
A, PHI = 0.7, 0.4  # y = A sin(2 pi f (t - t0) + PHI): P = A cos(PHI), Q = A sin(PHI) for harmonic 1
T0 = 0.25


def stream(periods: int, cut: list[tuple[float, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the sine from t0 over ``periods`` periods, those with time (in periods since t0) inside any of
    the open intervals ``cut`` left out; plus the third harmonic, which must not leak into the first."""
    u = np.arange(periods * K + 1) / K
    keep = np.ones(u.size, dtype=bool)
    for lo, hi in cut:
        keep &= ~((u > lo) & (u < hi))
    u = u[keep]
    y = A * np.sin(2 * np.pi * u + PHI) + 0.2 * np.cos(6 * np.pi * u)
    return T0 + u / F, y


def fixed(**analysis: Any) -> AnalysisConfig:
    """The fixed scheme: N settle periods, then M averaged (so the periods a point takes are known)."""
    return AnalysisConfig(**{"harmonics": (1, 3), "criterion": "fixed", "settle_periods": 2, "average_periods": 10,
                             "skip_periods": 0, "max_periods": 400, **analysis})


def test_the_periods_a_gap_touches_are_marked_and_the_others_are_exact() -> None:
    t, y = stream(10, [(3.6, 5.2)])  # periods 4, 5 and 6 (u in [3, 6)) hold part of the gap
    integ = PeriodIntegrator(F, (1, 3), 1, T0, max_gap=0.1)
    # fed in uneven chunks, the gap split between two of them: the marks do not depend on the chunks
    marks, ps, qs = [], [], []
    for part in np.array_split(np.arange(t.size), [50, 230, 233, 400]):
        p, q, whole = integ.feed_marked(t[part], y[part])
        marks.extend(whole.tolist())
        ps.append(p)
        qs.append(q)
    assert marks == [True, True, True, False, False, False, True, True, True, True]
    p, q = np.concatenate(ps), np.concatenate(qs)
    for i in np.flatnonzero(marks):
        assert p[i, 0, 0] == pytest.approx(A * math.cos(PHI), abs=1e-12)
        assert q[i, 0, 0] == pytest.approx(A * math.sin(PHI), abs=1e-12)
        assert q[i, 0, 1] == pytest.approx(0.2, abs=1e-12)
    # the discarded periods are what the trapezoidal rule makes of the straight line across the gap: wrong
    assert abs(complex(p[4, 0, 0], q[4, 0, 0]) - A * cmath.exp(1j * PHI)) > 0.1
    # the marks change no coefficient: feed() without a gap limit gives the same, bit for bit
    p_all, q_all = PeriodIntegrator(F, (1, 3), 1, T0).feed(t, y)
    p_one, q_one, _ = PeriodIntegrator(F, (1, 3), 1, T0, max_gap=0.1).feed_marked(t, y)
    assert np.array_equal(p_all, p_one) and np.array_equal(q_all, q_one)
    assert np.allclose(p_all, p, rtol=0, atol=1e-14) and np.allclose(q_all, q, rtol=0, atol=1e-14)


def test_a_gap_ending_on_a_period_edge_leaves_the_next_period_whole() -> None:
    t, y = stream(8, [(3.5, 5.0)])  # the gap ends on the sample at u = 5 exactly: period 6 starts there
    _, _, whole = PeriodIntegrator(F, (1,), 1, T0, max_gap=0.25).feed_marked(t, y)
    assert whole.tolist() == [True, True, True, False, False, True, True, True]


def test_short_gaps_are_no_gaps() -> None:
    t, y = stream(6, [(1.5, 1.5 + 3.5 / K)])  # three samples missing: 4/64 of a period, under the limit
    _, _, whole = PeriodIntegrator(F, (1, 3), 1, T0, max_gap=0.25 / 3).feed_marked(t, y)
    assert whole.all()


@pytest.mark.parametrize("cut, touched", [
    ([(3.6, 5.2)], 3),
    ([(0.0 + 1 / K, 0.5)], 1),  # the very first period
    ([(2.9, 3.1), (7.2, 7.4), (7.5, 7.9)], 3),  # two gaps in one period count it once
])
def test_the_point_is_exact_and_counts_the_periods_the_gaps_touched(cut: list[tuple[float, float]],
                                                                    touched: int) -> None:
    t, y = stream(40, cut)
    sampler = Autointegrator(F, A, ("y",), fixed(), t0=T0)
    for part in np.array_split(np.arange(t.size), 7):
        sampler.feed(t[part], y[:, None][part])
    assert sampler.done and not sampler.failure
    first, third = sampler.points()
    assert (first.periods, first.periods_discarded, third.periods_discarded) == (12, touched, touched)
    assert first.p == pytest.approx(A * math.cos(PHI), abs=1e-12)
    assert first.q == pytest.approx(A * math.sin(PHI), abs=1e-12)
    assert abs(complex(third.p, third.q) - 0.2j) < 1e-12
    if cut[0][0] < 2:  # a gap in the settle periods does not reach the average
        return
    # integrated across by the trapezoidal rule, the same gaps move the coefficient well past its accuracy; the
    # sampler's moment solve, which knows where the samples are, still gets this signal (a constant and harmonics up
    # to the highest measured) exactly, leaving out only a period with no sample inside it at all
    bridged = PeriodIntegrator(F, (1, 3), 1, T0)
    p, q = bridged.feed(t, y)
    assert np.max(np.abs(p[:, 0, 0] + 1j * q[:, 0, 0] - A * cmath.exp(1j * PHI))) > 1e-4
    across = Autointegrator(F, A, ("y",), fixed(), t0=T0, check_gaps=False)
    across.feed(t, y[:, None])
    (first_across, _) = across.points()
    empty = sum(math.floor(hi) - math.ceil(lo) for lo, hi in cut if math.floor(hi) > math.ceil(lo))
    assert first_across.periods_discarded == empty
    assert abs(complex(first_across.p, first_across.q) - A * cmath.exp(1j * PHI)) < 1e-12


def test_gaps_after_the_rules_stopped_are_not_counted() -> None:
    t, y = stream(30, [(20.2, 20.6)])
    sampler = Autointegrator(F, A, ("y",), fixed(), t0=T0)
    sampler.feed(t, y[:, None])
    assert [p.periods_discarded for p in sampler.points()] == [0, 0]


def test_gaps_in_most_periods_fail_the_point() -> None:
    # a gap in three periods of every four: 12 whole periods take 48, 36 of them discarded
    cut = [(i + 0.3, i + 0.6) for i in range(200) if i % 4 != 3]
    t, y = stream(200, cut)
    sampler = Autointegrator(F, A, ("y",), fixed(), t0=T0)
    sampler.feed(t, y[:, None])
    assert sampler.done
    assert sampler.failure == ("2 Hz: 36 of 48 periods discarded for gaps in the samples longer than 41.7 ms "
                               "(0.0833 of a period), more than max_discarded_percent = 50 %")
    with pytest.raises(GapsError, match="36 of 48 periods discarded"):
        sampler.points()
    # the share allowed is the user's
    tolerant = Autointegrator(F, A, ("y",), fixed(max_discarded_percent=80.0), t0=T0)
    tolerant.feed(t, y[:, None])
    assert [p.periods_discarded for p in tolerant.points()] == [36, 36]


def test_a_stream_of_gaps_only_fails_once_it_has_discarded_more_than_its_share_of_the_budget() -> None:
    t, y = stream(300, [(i + 0.3, i + 0.6) for i in range(300)])
    sampler = Autointegrator(F, A, ("y",), fixed(max_periods=50), t0=T0)
    for part in np.array_split(np.arange(t.size), 30):
        sampler.feed(t[part], y[:, None][part])
        if sampler.done:
            break
    # 26 of the 50 periods the budget holds are more than half of them, whatever the other 24 would be
    assert sampler.failure == ("2 Hz: 26 of 26 periods discarded for gaps in the samples longer than 41.7 ms "
                               "(0.0833 of a period), more than max_discarded_percent = 50 % of the 50 periods the "
                               "point may span")
    assert sampler.periods == 0


def three_of_four_gapped(periods: int, until: int) -> tuple[np.ndarray, np.ndarray]:
    """``periods`` periods of the sine; up to period ``until`` a gap in periods 1 to 3 of every 4 (the 4th whole)."""
    return stream(periods, [(i + 0.3, i + 0.6) for i in range(until) if i % 4 != 3])


def never_stopping(**analysis: Any) -> AnalysisConfig:
    """The fixed scheme averaging more periods than the budget holds: its rules stop only at the budget."""
    return fixed(average_periods=1000, **analysis)


@pytest.mark.parametrize("percent", [50.0, 33.3, 70.0])
@pytest.mark.parametrize("chunks", [1, 9, 400])
def test_a_point_fails_at_the_first_period_that_makes_failing_certain(percent: float, chunks: int) -> None:
    """Three periods of every four discarded, a budget of 400 periods: the point fails at the discarded period
    that takes the count past ``percent`` of the 400, long before the periods spanned reach them."""
    budget = 400
    allowed = math.floor(percent * budget / 100)  # 200, 133 and 280 discarded periods fit within the share
    pattern = [i % 4 != 3 for i in range(budget)]  # period i + 1 discarded
    spanned = next(n for n in range(1, budget + 1) if sum(pattern[:n]) == allowed + 1)
    t, y = three_of_four_gapped(budget, budget)
    sampler = Autointegrator(F, A, ("y",), never_stopping(max_periods=budget, max_discarded_percent=percent), t0=T0)
    assert sampler.max_periods == budget and sampler.discard_limit == allowed
    for part in np.array_split(np.arange(t.size), chunks):
        sampler.feed(t[part], y[:, None][part])
        if sampler.done:
            break
    assert sampler.discarded == allowed + 1  # and no period after it taken
    assert sampler.failure == (f"2 Hz: {allowed + 1} of {spanned} periods discarded for gaps in the samples longer "
                               f"than 41.7 ms (0.0833 of a period), more than max_discarded_percent = {percent:g} % "
                               f"of the {budget} periods the point may span")
    assert spanned < budget  # for 50 %: period 267, where the judgement at the budget would have come at 400


def test_a_point_that_can_still_pass_is_not_failed_early() -> None:
    """The same pattern stopped one discarded period short of the share, whole periods after it: 200 of the 400
    periods the budget holds are discarded, exactly half, not more, and the point is measured."""
    budget = 400
    t, y = three_of_four_gapped(budget + 210, 266)  # periods 1 to 266 hold 200 gaps, every later one is whole
    sampler = Autointegrator(F, A, ("y",), never_stopping(max_periods=budget), t0=T0)
    for part in np.array_split(np.arange(t.size), 40):
        sampler.feed(t[part], y[:, None][part])
        assert not sampler.failure, sampler.failure
        if sampler.done:
            break
    assert sampler.done and sampler.discarded == sampler.discard_limit == 200
    first, _ = sampler.points()  # judged at period 400 (200 of 400: half) and at every period after it
    assert (first.periods, first.periods_discarded) == (budget, 200)
    assert first.p == pytest.approx(A * math.cos(PHI), abs=1e-12)
    # one more discarded period, and the same point fails the moment it comes
    t, y = three_of_four_gapped(budget + 210, 267)
    sampler = Autointegrator(F, A, ("y",), never_stopping(max_periods=budget), t0=T0)
    sampler.feed(t, y[:, None])
    assert sampler.failure.startswith("2 Hz: 201 of 267 periods discarded")


def test_the_share_allowed_of_the_budget_is_the_judgement_of_the_whole_point() -> None:
    """A point whose rules stop before its budget is judged on the periods it spanned: 36 of 48 discarded fail it
    at 50 % though 36 is well within half of the budget of 400 (the early failure takes nothing away from that)."""
    t, y = three_of_four_gapped(200, 200)
    sampler = Autointegrator(F, A, ("y",), fixed(), t0=T0)
    sampler.feed(t, y[:, None])
    assert sampler.discard_limit == 200 and sampler.failure.startswith("2 Hz: 36 of 48 periods discarded")
    assert sampler.failure.endswith("more than max_discarded_percent = 50 %")


@pytest.mark.parametrize("periods", [1, 7, 256, 400, 6000, 20000])
@pytest.mark.parametrize("percent", [0.0, 0.1, 12.5, 33.3, 50.0, 66.7, 99.9])
def test_the_discard_limit_is_the_most_the_share_allows(periods: int, percent: float) -> None:
    limit = discard_limit(periods, percent)
    assert 0 <= limit <= periods
    assert not too_many_discarded(limit, periods, percent)
    assert limit == periods or too_many_discarded(limit + 1, periods, percent)


def test_the_progress_line_says_how_many_periods_were_discarded_and_how_many_may_be() -> None:
    import io

    from bodebench.apps.progress import ProgressPrinter
    from bodebench.bench.events import PointProgress, PointStarted

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    screen = Terminal()
    printer = ProgressPrinter("sweep", 1, screen, refresh_s=0.0)
    printer(PointStarted(0, 10.0))
    printer(PointProgress(0, 10.0, 0, (), discarded=2999, discard_limit=3000))
    assert screen.getvalue().endswith("10 Hz, period 0 (2999 discarded for gaps, at most 3000 allowed), ETA --")
    assert PointProgress(0, 10.0, 5, ()).gaps() == ""


def test_results_files_keep_the_count_and_older_files_load(tmp_path: Path) -> None:
    t, y = stream(40, [(3.6, 5.2)])
    sampler = Autointegrator(F, A, ("y",), fixed(), t0=T0)
    sampler.feed(t, y[:, None])
    points = sampler.points()
    from bodebench.core.response import FrequencyResponse

    save_response(FrequencyResponse(points, config={}, case="c"), tmp_path)
    assert [p.periods_discarded for p in load_response(tmp_path)] == [3, 3]
    csv = tmp_path / "response.csv"
    lines = [line for line in csv.read_text().splitlines() if not line.startswith("#")]
    csv.write_text("".join(",".join(line.split(",")[:21]) + "\n" for line in lines))  # a version-3 file
    assert [p.periods_discarded for p in load_response(tmp_path)] == [0, 0]


def test_a_gap_limit_under_the_sample_interval_is_refused() -> None:
    data = {"plant": {"model": "lag"}, "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 50.0]},
            "analysis": {"harmonics": [1], "max_gap_cycles": 0.04},
            "bench": {"transport": "can", "rate_hz": 1000.0, "clock": "lockstep"},
            "can": {"interface": "virtual", "channel": "x"}, "safety": {"max_amplitude": 0.02}, "simulator": {}}
    with pytest.raises(ConfigError, match=r"^gaps.toml: analysis.max_gap_cycles: 0.04: at 50 Hz one sample "
                                          r"interval at bench.rate_hz = 1000 is already 0.05 cycles"):
        parse_config(data, "gaps.toml")


# ------------------------------------------------------------------------------------------- on the virtual bus

RATE_HZ = 1000.0
LAG = ([2.0], [0.02, 1.0])  # G(s) = 2 / (0.02 s + 1)


def exact(frequency_hz: float, amplitude: float) -> complex:
    """What the bench measures of the lag: the drive holds each setpoint for a period and samples once a period,
    so the response is the zero-order-hold discretisation G_d(z) at z = exp(j w h) (scipy's cont2discrete)."""
    num_d, den_d, _ = signal.cont2discrete(LAG, 1 / RATE_HZ, method="zoh")
    z = cmath.exp(2j * math.pi * frequency_hz / RATE_HZ)
    return amplitude * complex(np.polyval(np.ravel(num_d), z) / np.polyval(den_d, z))


@pytest.mark.slow
def test_a_stalling_drive_on_the_virtual_bus_measures_the_exact_response(tmp_path: Path) -> None:
    freqs = [5.0, 12.0]
    data = {
        "plant": {"model": "lag", "time_constant": 0.02, "gain": 2.0},
        "excitation": {"amplitude": 0.01, "frequencies_hz": freqs},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.01},
        "bench": {"transport": "can", "rate_hz": RATE_HZ, "clock": "lockstep", "timebase": "counter"},
        "can": {"interface": "virtual", "channel": f"gaps-{uuid.uuid4().hex[:8]}"},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
        # 60 ms without an answer every second: over a quarter of a period at both frequencies
        "simulator": {"faults": {"stall_every_s": 1.0, "stall_s": 0.06}},
    }
    out = tmp_path / "out"
    outcome = SweepProcedure(parse_config(data, "gaps.toml"), out).run()[0]
    assert outcome.session is not None and not outcome.session.refused
    measured = load_response(out)
    assert [p.frequency_hz for p in measured] == freqs
    for p in measured:
        z = exact(p.frequency_hz, p.amplitude)
        assert p.converged and p.periods_discarded > 0, p
        assert abs(complex(p.p, p.q) - z) <= 0.01 / 100 * abs(z) + p.uncertainty, p
    # one stall a second, each touching one or two periods: the count is what the stalls in the point's time make
    for p in measured:
        seconds = (p.periods + p.periods_discarded) / p.frequency_hz
        assert math.floor(seconds) - 1 <= p.periods_discarded <= 2 * math.ceil(seconds) + 1, p
    runs = json.loads((out / "response.json").read_text())["runs"]
    assert runs[-1]["samples"]["periods_discarded"] == sum(p.periods_discarded for p in measured)
    # the replay discards the same periods: bit for bit the points measured
    again = reanalyse(out)
    def exactly(p: Any) -> tuple[str, ...]:
        return tuple(str(v) for v in dataclasses.astuple(p))  # NaN equal to NaN, every float to the last bit

    assert [exactly(p) for p in again.response] == [exactly(p) for p in measured]
    # integrated across the stalls, the moment solve still fits a sine to the samples that are there: the lag's
    # output is one, so even the periods the stalls cut give it (the trapezoidal rule alone, bridging the stalls by
    # straight lines, put points 57 to over 100 times outside what they stated); gaps are left out for what the
    # basis does not hold (noise, harmonics above the highest measured)
    across = {p.frequency_hz: p for p in reanalyse(out, max_gap_cycles=1.0).response}
    for p in measured:
        z = exact(p.frequency_hz, p.amplitude)
        wrong = across[p.frequency_hz]
        assert wrong.periods_discarded == 0
        assert abs(complex(wrong.p, wrong.q) - z) <= 0.01 / 100 * abs(z), (p, wrong)


@pytest.mark.slow
def test_a_point_with_gaps_in_every_period_is_refused_and_the_drive_left_safe(tmp_path: Path) -> None:
    from bodebench.bench.connection import plan_link
    from bodebench.bench.events import PointFinished
    from bodebench.bench.session import BenchSession

    data = {
        "plant": {"model": "lag", "time_constant": 0.02, "gain": 2.0},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.01, "max_periods": 20},
        "bench": {"transport": "can", "rate_hz": RATE_HZ, "clock": "lockstep", "timebase": "counter"},
        "can": {"interface": "virtual", "channel": f"gaps-{uuid.uuid4().hex[:8]}"},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
        # 60 ms without an answer every 200 ms, once a period: more than the 50 ms a period of 5 Hz may lack
        "simulator": {"faults": {"stall_every_s": 0.2, "stall_s": 0.06}},
    }
    case = parse_config(data, "gaps.toml").cases[0]
    finished: list[PointFinished] = []
    session = BenchSession(case, plan_link(case), tmp_path / "out",
                           lambda e: finished.append(e) if isinstance(e, PointFinished) else None)
    result = session.run()
    assert result.completed and session.ended is not None
    assert session.ended.drive_state() == "drive left at setpoint 0, disabled"
    # 11 of the 20 periods the budget holds are more than half of them: no need to wait for the other 9
    why = ("5 Hz: 11 of 11 periods discarded for gaps in the samples longer than 50 ms (0.25 of a period), more "
           "than max_discarded_percent = 50 % of the 20 periods the point may span")
    assert session.refused == [(5.0, why)]
    assert finished[0].refused == why and not finished[0].points
    assert result.periods_discarded == 11 and not session.response.points
    assert not (tmp_path / "out").exists()  # nothing measured, nothing written


@pytest.mark.slow
def test_a_stalled_pacing_process_leaves_out_what_answered_a_stale_setpoint(tmp_path: Path) -> None:
    """On the realtime clock the bus worker (its own process) is stopped for 0.4 s mid-point, as a loaded bench PC
    stops it: the drive holds the last setpoint meanwhile, so the feedback of that stretch answers no sine. It is
    left out like a gap: the periods it touched are discarded and counted, and the gain is the exact one."""
    import multiprocessing
    import os
    import signal as signals
    import threading

    from bodebench.bench.events import PointProgress

    f = 5.0
    data = {
        "plant": {"model": "lag", "time_constant": 0.02, "gain": 2.0},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [f]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.05},
        "bench": {"transport": "can", "rate_hz": RATE_HZ, "clock": "realtime", "timebase": "counter",
                  "worker": "process"},
        "can": {"interface": "virtual", "channel": f"stale-{uuid.uuid4().hex[:8]}"},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
        "simulator": {},
    }
    stopped: list[int] = []

    def listener(event: object) -> None:
        if isinstance(event, PointProgress) and event.periods >= 8 and not stopped:
            worker = multiprocessing.active_children()[0]
            assert worker.pid is not None
            stopped.append(worker.pid)
            os.kill(worker.pid, signals.SIGSTOP)
            threading.Timer(0.4, os.kill, (worker.pid, signals.SIGCONT)).start()

    out = tmp_path / "out"
    outcome = SweepProcedure(parse_config(data, "stale.toml"), out, listener=listener).run()[0]
    assert stopped and outcome.result is not None
    assert outcome.result.stale_samples > 0
    (p,) = load_response(out)
    assert p.converged and p.periods_discarded >= 2, p
    gain = abs(exact(f, 1.0))  # the drive's clock holds each setpoint a period: the discretised lag's gain
    assert abs(p.gain - gain) <= 0.05 / 100 * gain + p.uncertainty / p.amplitude, p
    runs = json.loads((out / "response.json").read_text())["runs"]
    assert runs[-1]["samples"]["stale_setpoint"] == outcome.result.stale_samples


@pytest.mark.slow
def test_a_drive_that_answers_only_after_t0_is_measured_from_its_first_whole_period(tmp_path: Path) -> None:
    """On the realtime clock the drive says nothing for its first second (booting, its clock going on): the
    first point's ramp (0.4 s at 5 Hz) is over before any sample comes, so period 1 is the first whole period
    after the first sample, and the point has the exact gain."""
    f = 5.0
    data = {
        "plant": {"model": "lag", "time_constant": 0.02, "gain": 2.0},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [f]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.05},
        "bench": {"transport": "can", "rate_hz": RATE_HZ, "clock": "realtime", "timebase": "counter"},
        "can": {"interface": "virtual", "channel": f"late-{uuid.uuid4().hex[:8]}"},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
        "simulator": {"faults": {"silent_until_s": 1.0}},
    }
    out = tmp_path / "out"
    outcome = SweepProcedure(parse_config(data, "late.toml"), out).run()[0]
    assert outcome.session is not None and not outcome.session.refused
    (p,) = load_response(out)
    gain = abs(exact(f, 1.0))  # the drive's clock holds each setpoint a period: the discretised lag's gain
    assert p.converged and abs(p.gain - gain) <= 0.05 / 100 * gain + p.uncertainty / p.amplitude, (p.status, p)


def test_periods_whose_reference_shows_no_sine_are_discarded() -> None:
    """Two-channel mode: in periods 4 to 6 the echoed setpoint reads zero (the drive saw no sine), which would
    divide by nothing; they are discarded, and the point is the exact ratio of the others."""
    settings = fixed(harmonics=(1,))
    sampler = Autointegrator(F, 1.0, ["y"], settings, t0=T0, reference="echo")
    u = np.arange(40 * K + 1) / K
    echo = 0.5 * np.sin(2 * np.pi * u)
    echo[(u >= 3) & (u <= 6)] = 0.0
    y = np.column_stack([A * np.sin(2 * np.pi * u + PHI), echo])
    sampler.feed(T0 + u / F, y)
    assert sampler.done and not sampler.failure
    (point,) = sampler.points()
    # output over input, times the commanded amplitude: A / 0.5 at phase PHI
    assert complex(point.p, point.q) == pytest.approx(2 * A * cmath.exp(1j * PHI), abs=1e-12)
    assert point.periods_discarded == 3


@pytest.mark.parametrize("reference", [None, "echo"])
@pytest.mark.parametrize("chunk", [1, 3, K - 1, K, 2 * K + 5, 7 * K])
def test_the_verdicts_do_not_depend_on_how_the_samples_are_split(reference: str | None, chunk: int) -> None:
    """The sampler fed a noisy stream (with a gap, and in two-channel mode an echo that shows no sine for three
    periods) in chunks of any size, from a fraction of a period to several (in one-channel mode a few periods are
    taken on Python scalars, more on arrays): the same periods discarded, the same verdicts at the same periods,
    the same values to round-off."""
    settings = AnalysisConfig(harmonics=(1, 2), tolerance_percent=0.5, skip_periods=1, max_periods=300)
    rng = np.random.default_rng(4)
    u = np.arange(300 * K + 1) / K
    keep = ~((u > 20.3) & (u < 21.6))  # a gap in periods 21 and 22
    u = u[keep]
    y = A * np.sin(2 * np.pi * u + PHI) + 0.2 * np.cos(4 * np.pi * u) + 0.02 * rng.normal(size=u.size)
    columns = [y]
    if reference is not None:
        echo = 0.5 * np.sin(2 * np.pi * u) + 0.002 * rng.normal(size=u.size)
        echo[(u >= 40) & (u <= 43)] = 0.0
        columns.append(echo)
    t, samples = T0 + u / F, np.column_stack(columns)

    def run(size: int) -> Autointegrator:
        sampler = Autointegrator(F, 1.0, ["y"], settings, t0=T0, reference=reference, check_gaps=True)
        for i in range(0, t.size, size):
            sampler.feed(t[i:i + size], samples[i:i + size])
            if sampler.done:
                break
        assert sampler.done and not sampler.failure
        return sampler

    whole, split = run(t.size), run(chunk)
    assert split.discarded == whole.discarded == 2 + 3 * (reference is not None)
    for a, b in zip(whole.points(), split.points(), strict=True):
        assert (a.periods, a.status) == (b.periods, b.status)
        assert complex(b.p, b.q) == pytest.approx(complex(a.p, a.q), abs=1e-12)
        assert b.uncertainty == pytest.approx(a.uncertainty, rel=1e-9, abs=1e-12)
