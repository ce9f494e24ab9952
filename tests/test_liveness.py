"""The watch that tells a drive that stopped answering from one that measures: a held value, a silent fundamental."""

from __future__ import annotations

import math

import numpy as np

from bodebench.core.liveness import FLAT_PERIODS, FlatWatch, no_fundamental
from bodebench.core.response import ResponsePoint
from bodebench.status import PointStatus


def test_a_channel_holding_one_value_for_whole_periods_is_named_and_a_moving_one_is_not() -> None:
    f, rate = 5.0, 1000.0
    t = np.arange(0, 2000) / rate  # 10 periods
    moving = 1e-9 * np.sin(2 * np.pi * f * t)  # tiny, but it moves
    frozen = np.where(t < 0.5, np.sin(2 * np.pi * f * t), 0.0)  # at rest from 0.5 s (2.5 periods)
    watch = FlatWatch(("position", "setpoint_echo"), f)
    for part in np.array_split(np.arange(t.size), 13):  # the verdict does not depend on how the stream is cut
        watch.add(t[part], np.column_stack((moving[part], frozen[part])))
        held = t[part][-1] - 0.5
        assert bool(watch.stuck()) == (held > FLAT_PERIODS / f)
    line = watch.stuck()
    assert line.startswith("setpoint_echo held 0 for") and "periods) while the sine ran" in line


def test_a_value_that_comes_back_restarts_the_count() -> None:
    watch = FlatWatch(("y",), 1.0)
    watch.add(np.array([0.0, 1.0, 1.9]), np.array([[3.0], [3.0], [3.0]]))
    assert not watch.stuck()
    watch.add(np.array([2.5]), np.array([[3.0]]))
    assert watch.stuck()
    watch.add(np.array([2.6, 4.5]), np.array([[3.1], [3.0]]))
    assert not watch.stuck()  # 3.0 again, but only since 4.5 s


def point(harmonic: int, status: PointStatus, p: float) -> ResponsePoint:
    return ResponsePoint(frequency_hz=2.0, harmonic=harmonic, channel="position", amplitude=1.0, p=p, q=0.0,
                         periods=10, converged=status is PointStatus.CONVERGED, status=status,
                         uncertainty=0.0, uncertainty_1d=0.0, within_eps=True, periods_needed=0,
                         thd=math.nan, coherence=1.0)


def test_a_fundamental_below_resolution_is_no_response_and_a_small_harmonic_is_a_measurement() -> None:
    assert no_fundamental([point(1, PointStatus.CONVERGED, 0.5), point(3, PointStatus.BELOW_RESOLUTION, 0.0)]) == ""
    line = no_fundamental([point(1, PointStatus.BELOW_RESOLUTION, 0.0), point(3, PointStatus.BELOW_RESOLUTION, 0.0)])
    assert line.startswith("position shows no response at harmonic 1")


def test_coefficients_beyond_any_sensor_are_discarded_not_overflowed() -> None:
    """Feedback of 1e160 (a corrupt float that passed every check): its squares would overflow the rules' sums; such
    periods are discarded as non-finite ones are, and a point made of nothing else fails saying so (once it has
    discarded more than half of the 30 periods its budget holds)."""
    from bodebench.core.autointegration import MAX_COEFFICIENT, Autointegrator
    from bodebench.io.config import AnalysisConfig

    f = 2.0
    t = np.arange(0, 30 * 64 + 1) / (64 * f)
    for scale, expected_discarded in ((1e160, 16), (MAX_COEFFICIENT / 10, 0)):
        sampler = Autointegrator(f, 1.0, ("y",), AnalysisConfig(harmonics=(1,), max_periods=30), t0=0.0)
        for part in np.array_split(np.arange(t.size), 30):  # a few periods at a time, as a bench feeds them
            sampler.feed(t[part], scale * np.sin(2 * np.pi * f * t[part])[:, None])
        assert sampler.discarded == expected_discarded
        if expected_discarded:
            assert sampler.done and "16 of 16 periods discarded" in sampler.failure
        else:
            assert sampler.done and not sampler.failure


def test_a_host_that_stalled_is_not_a_drive_that_stopped() -> None:
    """The host's setpoint held still for 3 periods (its process stalled, nothing went out), the drive's output held
    still with it: not the drive's fault, no verdict; the same output while the host's sine moved is one."""
    f = 10.0
    t = np.arange(0, 50) / 100.0  # 5 periods
    frozen = np.zeros((t.size, 1))
    stalled = FlatWatch(("position",), f)
    stalled.add(t, frozen, driven=np.zeros(t.size, dtype=bool))
    assert stalled.stuck() == ""
    moving = FlatWatch(("position",), f)
    moving.add(t, frozen, driven=np.ones(t.size, dtype=bool))
    assert moving.stuck().startswith("position held 0 for")


def test_a_host_that_stalls_now_and_then_neither_hides_a_drive_that_stopped_nor_is_blamed_for_its_stalls() -> None:
    """On a loaded host a tick now and then goes out late (the setpoint does not move there). The drive's output
    held still throughout: the driven time still adds up to a verdict, a stall only pauses the count; the held time
    stated is the driven time, not the wall time."""
    f = 10.0
    t = np.arange(0, 100) / 100.0  # 10 periods
    frozen = np.zeros((t.size, 1))
    driven = np.arange(t.size) % 10 != 0  # one tick in ten stalled
    watch = FlatWatch(("position",), f)
    for part in np.array_split(np.arange(t.size), 7):
        watch.add(t[part], frozen[part], driven=driven[part])
    line = watch.stuck()
    assert line.startswith("position held 0 for 0.9 s (9 periods)"), line  # 90 of the 99 intervals driven
