"""The per-period coefficients of one series and their running sums (:class:`SeriesHistory`).

Every rule reads a series through this class: window means, spreads and lag correlations in O(1) from running
sums. Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math

import numpy as np

_EPS = float(np.finfo(float).eps)  # relative round-off of one float operation (the running sums' error bounds)
_SMALL_EXTEND = 8  # periods up to which extend() works on Python scalars (cheaper than numpy's per-call cost)


class SeriesHistory:
    """Per-period coefficients Z(i) = P(i) + jQ(i), i = 1..n, of one series, with running sums.

    Running sums of Z, of |Z - Z(1)|^2 and of (Z(j) - Z(1)) conj(Z(j-k) - Z(1)), k = 1, 2 (taken about the first
    value, so that the sums of squares of a steady series do not cancel catastrophically) make every window
    mean, spread and lag correlation O(1). Each is kept as a Python list, for the single entries a rule reads
    every period (a list serves those several times faster), and as a numpy array with the same values, for work
    on many periods at once; periods appended one by one reach the arrays when the arrays are next read
    (:meth:`arrays`), in one slice each.
    """

    def __init__(self) -> None:
        self._z = np.empty(256, dtype=complex)
        self._cum = np.zeros(257, dtype=complex)  # _cum[i] = Z(1) + ... + Z(i)
        self._cum2 = np.zeros(257)  # _cum2[i] = |Z(1) - Z(1)|^2 + ... + |Z(i) - Z(1)|^2
        self._lag = np.zeros(257, dtype=complex)  # _lag[i] = sum over j = 2..i of (Z(j) - Z(1)) conj(Z(j-1) - Z(1))
        self._lag2 = np.zeros(257, dtype=complex)  # _lag2[i] = sum over j = 3..i of (Z(j) - Z(1)) conj(Z(j-2) - Z(1))
        self._first = 0j  # Z(1)
        self._z_list: list[complex] = []
        self._cum_list: list[complex] = [0j]
        self._cum2_list: list[float] = [0.0]
        self._lag_list: list[complex] = [0j]
        self._lag2_list: list[complex] = [0j]
        self.n = 0
        self._synced = 0  # periods whose entries the arrays hold

    def extend(self, z: np.ndarray) -> None:
        """Append the coefficients of the next periods (complex array)."""
        z = np.asarray(z, dtype=complex).reshape(-1)
        if z.size == 0:
            return
        if z.size <= _SMALL_EXTEND:
            for v in z.tolist():
                self.append(v)
            return
        self._sync()
        n, need = self.n, self.n + z.size
        self._reserve(need)
        self._z[n:need] = z
        if n == 0:
            self._first = complex(z[0])
        z0 = self._first
        self._cum[n + 1:need + 1] = self._cum[n] + np.cumsum(z)
        lo = max(n - 2, 0)
        centred = self._z[lo:need] - z0  # Z(lo+1..need) - Z(1)
        self._cum2[n + 1:need + 1] = self._cum2[n] + np.cumsum(np.abs(centred[n - lo:]) ** 2)
        for sums, k in ((self._lag, 1), (self._lag2, 2)):
            # (Z(j) - Z(1)) conj(Z(j-k) - Z(1)) for j = max(n, k)+1..need; the sums up to period k are zero
            count = need - max(n, k)
            if count > 0:
                products = centred[centred.size - count:] * np.conj(centred[centred.size - count - k:-k])
                sums[need - count + 1:need + 1] = sums[need - count] + np.cumsum(products)
        self._z_list.extend(z.tolist())
        self._cum_list.extend(self._cum[n + 1:need + 1].tolist())
        self._cum2_list.extend(self._cum2[n + 1:need + 1].tolist())
        self._lag_list.extend(self._lag[n + 1:need + 1].tolist())
        self._lag2_list.extend(self._lag2[n + 1:need + 1].tolist())
        self.n = self._synced = need

    def append(self, v: complex) -> None:
        """Append the coefficient of the next period (to the lists; the arrays take it when next read)."""
        n = self.n
        v = complex(v)
        if n == 0:
            self._first = v
        z0 = self._first
        d = v - z0
        c = self._cum_list[n] + v
        c2 = self._cum2_list[n] + abs(d) ** 2
        zs = self._z_list
        lag = self._lag_list[n] + d * (zs[n - 1] - z0).conjugate() if n >= 1 else 0j
        lag2 = self._lag2_list[n] + d * (zs[n - 2] - z0).conjugate() if n >= 2 else 0j
        n += 1
        zs.append(v)
        self._cum_list.append(c)
        self._cum2_list.append(c2)
        self._lag_list.append(lag)
        self._lag2_list.append(lag2)
        self.n = n

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arrays, holding every period appended: Z (from index 0: Z(1)) and the running sums of Z, of
        |Z - Z(1)|^2 and of the lag-1 and lag-2 products (index i: the sum up to period i). Not to be written."""
        self._sync()
        return self._z, self._cum, self._cum2, self._lag, self._lag2

    def _sync(self) -> None:
        """Write the periods appended since the arrays were last read into them, one slice per array."""
        start, n = self._synced, self.n
        if start < n:
            self._reserve(n)
            self._z[start:n] = self._z_list[start:n]
            self._cum[start + 1:n + 1] = self._cum_list[start + 1:n + 1]
            self._cum2[start + 1:n + 1] = self._cum2_list[start + 1:n + 1]
            self._lag[start + 1:n + 1] = self._lag_list[start + 1:n + 1]
            self._lag2[start + 1:n + 1] = self._lag2_list[start + 1:n + 1]
            self._synced = n

    def all_finite(self, a: int, b: int) -> bool:
        """Whether Z(a+1..b) are all finite, from the running sum of squares (O(1)): a value that is not finite
        makes every later sum infinite or NaN. False also where the sum itself overflows (|Z| above ~1e154)."""
        return math.isfinite(self._cum2_list[b] - self._cum2_list[a])

    def _reserve(self, need: int) -> None:
        """Room for ``need`` periods in the arrays (the entries they hold are kept)."""
        if need > self._z.size:
            size = max(need, 2 * self._z.size)
            self._z = np.resize(self._z, size)
            for name in ("_cum", "_cum2", "_lag", "_lag2"):
                old = getattr(self, name)
                new = np.zeros(size + 1, dtype=old.dtype)
                new[: self._synced + 1] = old[: self._synced + 1]
                setattr(self, name, new)

    @property
    def values(self) -> np.ndarray:
        """Z(1..n) as a read-only view."""
        v = self.arrays()[0][: self.n]
        v.flags.writeable = False
        return v

    @property
    def cumulative(self) -> np.ndarray:
        """Running sums: ``cumulative[i] = Z(1) + ... + Z(i)``, i = 0..n (read-only view)."""
        c = self.arrays()[1][: self.n + 1]
        c.flags.writeable = False
        return c

    def at(self, i: int) -> complex:
        """Z(i), periods counted from 1."""
        return self._z_list[i - 1]

    def mean(self, a: int, b: int) -> complex:
        """Mean of Z over periods a+1..b."""
        cum = self._cum_list
        return (cum[b] - cum[a]) / (b - a)

    def lag_correlation(self, a: int, b: int) -> float:
        """|lag-1 autocorrelation| of Z over periods a+1..b (0: independent periods; near 1: smooth or turning)."""
        length = b - a
        if length < 3:
            return math.nan
        cum, z0 = self._cum_list, self._first
        shift = (cum[b] - cum[a]) / length - z0
        # sum of (Z(j) - m) conj(Z(j-1) - m) over j = a+2..b, expanded about Z(1)
        inner = cum[b] - cum[a + 1] - z0 * (length - 1)
        outer = cum[b - 1] - cum[a] - z0 * (length - 1)
        cov = (self._lag_list[b] - self._lag_list[a + 1]) - inner * shift.conjugate() - shift * outer.conjugate() \
            + (length - 1) * abs(shift) ** 2
        var = max(0.0, self._cum2_list[b] - self._cum2_list[a] - length * abs(shift) ** 2)
        return abs(cov) / var if var > 0.0 else math.nan

    def scatter(self, a: int, b: int) -> float:
        """Sum of |Z(i) - mean|^2 over periods a+1..b (output units squared)."""
        cum = self._cum_list
        shift = (cum[b] - cum[a]) / (b - a) - self._first
        return max(0.0, self._cum2_list[b] - self._cum2_list[a] - (b - a) * abs(shift) ** 2)

