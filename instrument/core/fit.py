"""A rational transfer function fitted to a measured frequency response, each point weighted by its stated
uncertainty (pure: no I/O).

The model, in the Laplace variable s = j 2 pi f:

    G(s) = (b_m s^m + ... + b_0) / (s^k (s^n + a_{n-1} s^{n-1} + ... + a_0)) * exp(-s tau)

with ``k`` 0 or 1 (an integrator) and an optional transport delay tau. The fit runs in two steps:

1. Sanathanan-Koerner iterations: the weighted linear least-squares problem B(s) - G_i A(s) = 0, each row divided
   by the previous iteration's |A(s_i)| and the point's standard deviation, until the poles settle (no delay in
   this step; with a delay, the measured phase is first corrected by a delay read off the phase slope at the
   highest frequencies);
2. a weighted nonlinear least-squares refinement of every parameter (scipy's ``least_squares``) on the real and
   imaginary residuals in units of each point's standard deviation.

The point's standard deviation comes from its stated 95 % interval along one direction (``uncertainty_1d``),
divided by the two-sided 95 % normal quantile, relative to the input amplitude. The parameters' covariance is
the inverse of J^T J at the solution (the residuals already in standard deviations; when the fit's chi-square
per degree of freedom exceeds 1, the covariance is scaled up by it, so that model error widens the intervals
instead of being hidden). Frequencies are scaled by the geometric mean of the measured ones while fitting, for
conditioning; the coefficients returned are in s (rad/s).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

__all__ = ["Q95", "TransferFit", "fit_transfer_function", "select_order"]

Q95 = 1.959963984540054
"""The two-sided 95 % quantile of the normal distribution: a 95 % half-width over it is one standard deviation."""

_SK_ITERATIONS = 30
_HUGE = 1e150


@dataclass(frozen=True)
class TransferFit:
    """A fitted transfer function and what the fit says of itself.

    num, den: coefficients in s, highest power first (den monic, without the integrator's s); integrator: a pole
    at s = 0 in front; delay_s: the transport delay tau, s (0: none fitted); covariance: of the parameters in the
    order [num..., den without its leading 1..., tau (when fitted)]; residuals: complex residual of each point in
    its standard deviations; chi2, dof: the sum of squared residuals and its degrees of freedom (2 per point minus
    the parameters); bic: the Bayesian information criterion for stated standard deviations, chi2 + k ln(n) with n
    the real equations, for comparing orders.
    """

    num: np.ndarray
    den: np.ndarray
    integrator: bool
    delay_s: float
    frequency_hz: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    chi2: float
    dof: int
    bic: float
    delay_fitted: bool = False
    names: tuple[str, ...] = field(default=())

    @property
    def parameters(self) -> np.ndarray:
        """The fitted parameters in the order of ``covariance`` and ``names``."""
        out = [*self.num, *self.den[1:]]
        if self.delay_fitted:
            out.append(self.delay_s)
        return np.array(out, dtype=float)

    @property
    def standard_errors(self) -> np.ndarray:
        """One standard deviation of each parameter (``names`` order); NaN where the covariance is too ill-conditioned
        to give one (a negative variance: the data do not determine that parameter at this order)."""
        variance = np.diag(self.covariance)
        return np.where(variance >= 0.0, np.sqrt(np.abs(variance)), np.nan)

    @property
    def stable(self) -> bool:
        """Every pole in the open left half-plane (the integrator's pole at 0 apart)."""
        roots = np.roots(self.den) if self.den.size > 1 else np.array([])
        return bool(np.all(roots.real < 0.0))

    def evaluate(self, frequency_hz: np.ndarray | Sequence[float] | float) -> np.ndarray:
        """The fitted G at ``frequency_hz`` (Hz)."""
        s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
        return _model(s, self.num, self.den, self.integrator, self.delay_s)

    @property
    def poles(self) -> np.ndarray:
        """The poles, rad/s (the integrator's 0 included)."""
        roots = np.roots(self.den) if self.den.size > 1 else np.array([], dtype=complex)
        return np.concatenate([roots, [0.0]]) if self.integrator else roots

    @property
    def zeros(self) -> np.ndarray:
        """The zeros, rad/s."""
        num = np.trim_zeros(self.num, "f")
        return np.roots(num) if num.size > 1 else np.array([], dtype=complex)

    @property
    def static_gain(self) -> float:
        """G(0) (without an integrator; with one, the gain of s G(s) at 0)."""
        return float(self.num[-1] / self.den[-1]) if self.den[-1] != 0 else math.inf

    def modes(self) -> list[tuple[float, float]]:
        """(natural frequency Hz, damping ratio) of each complex pole pair and real pole (damping 1 or more for a
        real pole: its corner frequency and 1), the integrator left out, sorted by frequency."""
        out = []
        seen: list[complex] = []
        for p in self.poles:
            if abs(p) == 0.0:
                continue
            if p.imag < 0 and any(abs(p.conjugate() - q) < 1e-9 * abs(p) for q in seen):
                continue
            seen.append(p)
            wn = abs(p)
            out.append((wn / (2 * np.pi), float(-p.real / wn) if p.imag != 0 else 1.0))
        return sorted(out)

    @property
    def order(self) -> tuple[int, int]:
        """(numerator degree, denominator degree), the integrator counted in the denominator."""
        return self.num.size - 1, self.den.size - 1 + int(self.integrator)


def _model(s: np.ndarray, num: np.ndarray, den: np.ndarray, integrator: bool, delay: float) -> np.ndarray:
    g = np.polyval(num, s) / np.polyval(den, s)
    if integrator:
        g = g / s
    return g * np.exp(-s * delay)


def _delay_from_phase(f: np.ndarray, h: np.ndarray) -> float:
    """A first delay: minus the phase slope (rad per rad/s) over the upper third of the frequencies, where a
    rational part's phase has flattened out; 0 when that slope says no delay."""
    order = np.argsort(f)
    f, h = f[order], h[order]
    upper = slice(max(0, 2 * f.size // 3 - 1), f.size)
    w = 2 * np.pi * f[upper]
    if w.size < 2:
        return 0.0
    phase = np.unwrap(np.angle(h[upper]))
    slope = np.polyfit(w, phase, 1)[0]
    return max(0.0, -float(slope))


def _sanathanan_koerner(s: np.ndarray, h: np.ndarray, sigma: np.ndarray, nb: int, na: int,
                        integrator: bool) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and monic denominator (in the scaled s) by Sanathanan-Koerner iterations."""
    target = h * s if integrator else h
    weight = 1.0 / (sigma * (np.abs(s) if integrator else 1.0))
    den = np.ones(na + 1)
    den_prev = np.ones(1)  # the first iteration unweighted by a denominator: Levy's linear fit
    num = np.zeros(nb + 1)
    for _ in range(_SK_ITERATIONS):
        with np.errstate(all="ignore"):
            magnitude = np.abs(np.polyval(den_prev, s))
        if not (np.all(np.isfinite(magnitude)) and np.all(magnitude > 0.0)):
            break  # a pole on the measured frequencies: the last finite iterate stands
        w = weight / magnitude
        # unknowns: b_nb..b_0, a_{na-1}..a_0 (a_na = 1): B(s) - G A(s) = G s^na
        cols = [s ** k for k in range(nb, -1, -1)] + [-target * s ** k for k in range(na - 1, -1, -1)]
        m = np.column_stack(cols) * w[:, None]
        rhs = target * s ** na * w
        lhs = np.vstack([m.real, m.imag])
        y = np.concatenate([rhs.real, rhs.imag])
        if not (np.all(np.isfinite(lhs)) and np.all(np.isfinite(y))):
            break
        x, *_ = np.linalg.lstsq(lhs, y, rcond=None)
        num = x[: nb + 1]
        den = np.concatenate([[1.0], x[nb + 1:]])
        if den_prev.size == den.size and np.allclose(den, den_prev, rtol=1e-12, atol=1e-14):
            break
        den_prev = den
    return num, den


def fit_transfer_function(frequency_hz: Sequence[float] | np.ndarray, response: Sequence[complex] | np.ndarray,
                          sigma: Sequence[float] | np.ndarray, numerator_order: int, denominator_order: int, *,
                          integrator: bool = False, delay: bool = False) -> TransferFit:
    """Fit G(s) of the given orders to ``response`` (complex, output per input unit) at ``frequency_hz`` (Hz),
    each point with standard deviation ``sigma`` (of its complex value along one direction, same units); see the
    module docstring. ``denominator_order`` counts the integrator. ValueError when the orders leave no degree of
    freedom or the data are not usable."""
    f = np.asarray(frequency_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    sd = np.asarray(sigma, dtype=float)
    if not (f.shape == h.shape == sd.shape and f.ndim == 1):
        raise ValueError("frequency_hz, response and sigma must be one-dimensional and of one length")
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.isfinite(h)) and np.all(sd > 0)
            and np.all(np.isfinite(sd))):
        raise ValueError("frequencies must be > 0, responses finite and standard deviations finite and > 0")
    na = denominator_order - int(integrator)
    nb = numerator_order
    if nb < 0 or na < 0 or nb > na + int(integrator):
        raise ValueError(f"orders {numerator_order}/{denominator_order}: need 0 <= numerator order <= denominator "
                         "order (a proper transfer function), the integrator counted in the denominator")
    n_params = nb + 1 + na + int(delay)
    dof = 2 * f.size - n_params
    if dof < 1:
        raise ValueError(f"{f.size} points give {2 * f.size} real equations: too few for {n_params} parameters")
    w0 = 2 * np.pi * float(np.exp(np.mean(np.log(f))))  # frequency scale for conditioning
    s = 2j * np.pi * f / w0
    tau0 = _delay_from_phase(f, h) if delay else 0.0
    h_sk = h * np.exp(2j * np.pi * f * tau0)  # the delay taken off before the linear step
    num_s, den_s = _sanathanan_koerner(s, h_sk, sd, nb, na, integrator)
    theta_delay = [tau0 * w0] if delay else []
    x0 = np.concatenate([num_s, den_s[1:], theta_delay])

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        return x[: nb + 1], np.concatenate([[1.0], x[nb + 1: nb + 1 + na]]), float(x[-1]) if delay else 0.0

    def residuals(x: np.ndarray) -> np.ndarray:
        num, den, tau = unpack(x)
        with np.errstate(all="ignore"):  # a trial step may put a pole on a measured frequency: a huge residual
            r = (_model(s, num, den, integrator, tau) - h) / sd
        return np.nan_to_num(np.concatenate([r.real, r.imag]), nan=_HUGE, posinf=_HUGE, neginf=-_HUGE)

    if np.any(np.abs(residuals(x0)) >= _HUGE):
        raise ValueError(f"orders {numerator_order}/{denominator_order}: no finite starting point (a pole on a "
                         "measured frequency)")
    solved = least_squares(residuals, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
    if np.any(np.abs(solved.fun) >= _HUGE):
        raise ValueError(f"orders {numerator_order}/{denominator_order}: the refinement left the finite range")
    x = solved.x
    num_s, den_s, tau_s = unpack(x)
    r = residuals(x)
    chi2 = float(r @ r)
    jac = solved.jac
    try:
        cov_scaled = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        cov_scaled = np.linalg.pinv(jac.T @ jac)
    cov_scaled *= max(1.0, chi2 / dof)
    # back from the scaled variable s/w0 to s: b_k (s/w0)^k -> b_k w0^-k s^k; the monic denominator's leading
    # w0^-na is divided out of both polynomials
    kb = np.arange(nb, -1, -1)
    ka = np.arange(na, -1, -1)
    lead = w0 ** (-na) * (w0 if integrator else 1.0) ** -1  # the integrator's 1/(s/w0) = w0/s
    num_scale = w0 ** (-kb.astype(float)) / lead
    den_scale = w0 ** (-ka.astype(float)) / w0 ** (-na)
    num = num_s * num_scale
    den = den_s * den_scale
    scales = np.concatenate([num_scale, den_scale[1:], [1.0 / w0] if delay else []])
    covariance = cov_scaled * np.outer(scales, scales)
    k = n_params
    n = 2 * f.size
    # the points' standard deviations are stated, not estimated: the Bayesian information criterion is
    # chi-square + k ln(n), which a pole-zero pair fitted to the noise does not lower
    bic = chi2 + k * math.log(n)
    names = tuple([f"b{i}" for i in kb] + [f"a{i}" for i in ka[1:]] + (["tau"] if delay else []))
    complex_residuals = (_model(s, num_s, den_s, integrator, tau_s) - h) / sd
    return TransferFit(num=num, den=den, integrator=integrator, delay_s=tau_s / w0, frequency_hz=f,
                       covariance=covariance, residuals=complex_residuals, chi2=chi2, dof=dof, bic=bic,
                       delay_fitted=delay, names=names)


def select_order(frequency_hz: Sequence[float] | np.ndarray, response: Sequence[complex] | np.ndarray,
                 sigma: Sequence[float] | np.ndarray, max_order: int, *, integrator: bool = False,
                 delay: bool = False, stable: bool = True) -> tuple[TransferFit, list[TransferFit]]:
    """Every proper order up to ``max_order`` (denominator), fitted; the one of least BIC among the stable
    ones (``stable``: a drive or a closed loop that was measured in steady state is stable), and all that could be
    fitted (those the data cannot determine are left out)."""
    fits = []
    for na in range(1, max_order + 1):
        for nb in range(0, na + 1):
            try:
                fits.append(fit_transfer_function(frequency_hz, response, sigma, nb, na, integrator=integrator,
                                                  delay=delay))
            except (ValueError, np.linalg.LinAlgError):
                continue
    if not fits:
        raise ValueError(f"no order up to {max_order} can be fitted to {len(np.atleast_1d(frequency_hz))} points")
    candidates = [fit for fit in fits if fit.stable] if stable else fits
    if not candidates:
        raise ValueError(f"no stable fit of order up to {max_order}: give --order, or look at the data")
    best = min(candidates, key=lambda fit: fit.bic)
    return best, fits
