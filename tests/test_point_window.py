"""The window of a bench point's analysed samples (bodebench.bench.window), against cases worked out by hand."""

from __future__ import annotations

import math

import numpy as np

from bodebench.bench.window import PointWindow, outside

F = 10.0  # Hz: a period of 0.1 s
DT = 0.01  # s between samples


def batch(start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """Samples start..stop-1 on the 10 ms grid; each value is its sample number."""
    k = np.arange(start, stop)
    return k * DT, k[:, None].astype(float)


def test_samples_up_to_t0_are_held_back_and_the_last_of_them_leads_period_1() -> None:
    window = PointWindow(t0=0.105, frequency_hz=F, longest_gap_s=0.025)
    t, v = batch(0, 8)  # 0 .. 70 ms: all before t0
    taken = window.take(t, v)
    assert taken.t.size == 0 and not taken.moved and taken.stale == 0
    t, v = batch(8, 14)  # 80 .. 130 ms: 110, 120, 130 ms after t0, led by the last sample at or before it (100 ms)
    taken = window.take(t, v)
    assert np.allclose(taken.t, [0.10, 0.11, 0.12, 0.13]) and taken.values[:, 0].tolist() == [10, 11, 12, 13]
    t, v = batch(14, 16)  # the leading sample is handed on once only
    assert window.take(t, v).values[:, 0].tolist() == [14, 15]
    assert window.t0 == 0.105


def test_a_drive_that_answers_after_t0_moves_t0_by_whole_periods() -> None:
    window = PointWindow(t0=0.105, frequency_hz=F, longest_gap_s=0.025)
    t, v = batch(33, 40)  # its first sample at 330 ms: t0 + 3 periods = 405 ms is the first whole period after it
    taken = window.take(t, v)
    assert taken.moved and math.isclose(window.t0, 0.405)
    assert taken.t.size == 0  # every sample of this batch lies before the new t0
    t, v = batch(40, 43)  # 400 ms leads (at or before 405 ms), then 410 and 420 ms
    taken = window.take(t, v)
    assert not taken.moved and taken.values[:, 0].tolist() == [40, 41, 42]


def test_stale_stretches_longer_than_the_longest_gap_are_left_out_and_counted() -> None:
    window = PointWindow(t0=0.0, frequency_hz=F, longest_gap_s=0.025)
    t, v = batch(0, 20)
    held = [(0.05, 0.08), (0.12, 0.135)]  # 30 ms: longer than 25 ms, left out; 15 ms: integrated as a short gap
    taken = window.take(t, v, held)
    numbers = taken.values[:, 0].tolist()
    assert taken.stale == 4 and [k for k in range(20) if k not in numbers and k != 0] == [5, 6, 7, 8]
    assert 12 in numbers and 13 in numbers
    # a stretch remembered from an earlier batch still covers the samples of the next one that fall in it
    window = PointWindow(t0=0.0, frequency_hz=F, longest_gap_s=0.025)
    window.take(*batch(0, 10), [(0.085, 0.125)])
    taken = window.take(*batch(10, 15))
    assert taken.stale == 3 and taken.values[:, 0].tolist() == [13, 14]


def test_outside_keeps_the_times_in_no_closed_stretch() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    assert outside(t, [(1.0, 2.0), (4.0, 5.0)]).tolist() == [True, False, False, True, False]
    assert outside(t, []).all()
