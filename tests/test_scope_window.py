"""The live scope's trace of the last two periods: what it shows, and that it holds no more than it shows."""

from __future__ import annotations

import math

import numpy as np

from bodebench.bench.session import ScopeWindow


def test_the_window_shows_the_last_two_periods_and_keeps_only_what_reaches_into_them() -> None:
    """Batches of every size, empty ones among them (a lockstep credit whose replies were all lost, a silent
    moment on the realtime clock), over a point of 800 periods: the view is exactly the samples of the last two
    periods at every batch, and the window never holds more batches than reach into them. An empty batch once
    stopped the pruning, and every later batch then concatenated the whole point."""
    f, rate = 8.0, 1000.0
    rng = np.random.default_rng(3)
    window = ScopeWindow(f)
    assert window.view() is None
    window.add(np.empty(0), np.empty(0), np.empty(0))
    assert window.view() is None  # nothing measured yet: nothing to show, and no error
    every_t: list[np.ndarray] = []
    tick, most = 0, 0
    while tick < 800 * rate / f:
        n = int(rng.choice([0, 0, 1, 7, 125, 400]))
        t = (tick + np.arange(n)) / rate
        tick += n
        window.add(t, np.sin(2 * math.pi * f * t), np.cos(2 * math.pi * f * t))
        every_t.append(t)
        most = max(most, len(window.chunks))
        view = window.view()
        if tick == 0:
            continue
        assert view is not None
        whole = np.concatenate(every_t)  # the whole record so far, cut by the same rule
        np.testing.assert_array_equal(view[0], whole[whole >= whole[-1] - 2.0 / f])
        np.testing.assert_allclose(view[1], np.sin(2 * math.pi * f * view[0]), atol=1e-12)
    # two periods are 250 samples: at most one batch wholly older than them, the rest reaching into them
    assert most <= 2 + math.ceil(2 * rate / f)
    smallest = min(t.size for t in every_t if t.size)
    assert smallest == 1 and len(window.chunks) < 300
