"""A transfer function fitted to a measured response (``bodebench fit``): the points of one harmonic and channel,
each weighted by its stated interval, given to :mod:`bodebench.core.fit`; the result as text and JSON."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from bodebench.core.fit import Q95, TransferFit, fit_transfer_function, select_order
from bodebench.core.response import PHASE_UNDEFINED_STATUSES, FrequencyResponse

__all__ = ["fit_data", "fit_lines", "fit_response", "fit_to_json", "fit_to_mat", "plot_fit", "to_control"]


def fit_data(response: FrequencyResponse, harmonic: int, channel: str | None) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray, str]:
    """(frequency Hz, complex response, standard deviation, channel) of the points that state an interval."""
    sel = response.select(harmonic=harmonic)
    channels = sel.channels
    if not channels:
        raise ValueError(f"no points of harmonic {harmonic}")
    name = channel if channel is not None else channels[0]
    if name not in channels:
        raise ValueError(f"no channel {name!r} (there are: {', '.join(channels)})")
    points = [p for p in sel.select(channel=name).points if p.status not in PHASE_UNDEFINED_STATUSES]
    latest = {p.frequency_hz: p for p in points}  # a frequency measured again: its latest point
    points = sorted(latest.values(), key=lambda p: p.frequency_hz)
    half = [p.uncertainty_1d if math.isfinite(p.uncertainty_1d) else p.uncertainty for p in points]
    usable = [(p, u) for p, u in zip(points, half, strict=True) if math.isfinite(u) and u > 0.0]
    if len(usable) < len(points):
        raise ValueError(f"{len(points) - len(usable)} of the points state no interval: a weighted fit needs one "
                         "for every point")
    f = np.array([p.frequency_hz for p, _ in usable])
    h = np.array([complex(p.p, p.q) / p.amplitude for p, _ in usable])
    sd = np.array([u / Q95 / p.amplitude for p, u in usable])
    return f, h, sd, name


def fit_response(response: FrequencyResponse, order: tuple[int, int] | None = None, *, max_order: int = 4,
                 harmonic: int = 1, channel: str | None = None, integrator: bool = False,
                 delay: bool = False) -> tuple[TransferFit, list[TransferFit], str]:
    """The fit of one harmonic and channel of ``response`` (default harmonic 1, the first channel): of
    ``order`` (numerator, denominator), or the order of least BIC up to ``max_order``. (the fit, every
    fit compared, the channel). ValueError saying why when there is nothing to fit."""
    f, h, sd, name = fit_data(response, harmonic, channel)
    if order is not None:
        fit = fit_transfer_function(f, h, sd, order[0], order[1], integrator=integrator, delay=delay)
        return fit, [fit], name
    best, fits = select_order(f, h, sd, max_order, integrator=integrator, delay=delay)
    return best, fits, name


def _polynomial(coefficients: np.ndarray) -> str:
    terms = []
    n = coefficients.size - 1
    for i, c in enumerate(coefficients):
        k = n - i
        power = "" if k == 0 else "s" if k == 1 else f"s^{k}"
        terms.append(f"{c:.6g}{' ' + power if power else ''}")
    return " + ".join(terms).replace("+ -", "- ")


def fit_lines(fit: TransferFit, fits: list[TransferFit], channel: str) -> list[str]:
    """The fit in words: the transfer function, its modes, its delay, and how well it fits."""
    den = _polynomial(fit.den)
    den = f"s ({den})" if fit.integrator else f"({den})" if fit.den.size > 1 else den
    delay = f" exp(-{fit.delay_s:.6g} s)" if fit.delay_fitted else ""
    worst = float(np.max(np.abs(fit.residuals))) if fit.residuals.size else math.nan
    lines = [f"{channel}: G(s) = ({_polynomial(fit.num)}) / {den}{delay}   (s in rad/s)",
             f"  order {fit.order[0]}/{fit.order[1]}" + (f" of {len(fits)} compared (least BIC)"
                                                          if len(fits) > 1 else ""),
             f"  chi-square {fit.chi2:.4g} for {fit.dof} degrees of freedom ({fit.chi2 / fit.dof:.3g} per degree; "
             f"about 1 when the model holds within the points' intervals); largest residual {worst:.3g} standard "
             "deviations"]
    per_degree = fit.chi2 / fit.dof
    if chi2.sf(fit.chi2, fit.dof) < 0.001:
        lines.append(f"  the model does not hold within the points' intervals (chi-square {per_degree:.3g} per degree "
                     "of freedom): the intervals below are widened by that factor's square root but describe this "
                     "model, not the plant; compare another order, an integrator or a delay")
    for name, value, error in zip(fit.names, fit.parameters, fit.standard_errors, strict=True):
        spread = f"+- {Q95 * error:.2g} (95 %)" if math.isfinite(error) else "(not determined at this order)"
        lines.append(f"  {name} = {value:.6g} {spread}")
    if not fit.stable:
        lines.append("  unstable: a pole in the right half-plane")
    for fn, zeta in fit.modes():
        lines.append(f"  mode: {fn:.5g} Hz" + (f", damping ratio {zeta:.4g}" if zeta < 1.0 else " (real pole)"))
    if not fit.integrator:
        lines.append(f"  static gain {fit.static_gain:.6g}")
    return lines


def fit_to_json(fit: TransferFit, fits: list[TransferFit], channel: str, harmonic: int) -> dict[str, Any]:
    """The fit as JSON types: coefficients (s in rad/s, highest power first), their covariance, the delay, the
    modes, the residuals in standard deviations, and the orders compared."""
    return {
        "channel": channel,
        "harmonic": harmonic,
        "model": "G(s) = num(s) / (s^integrator den(s)) * exp(-s delay_s), s in rad/s",
        "num": fit.num.tolist(),
        "den": fit.den.tolist(),
        "integrator": fit.integrator,
        "delay_s": fit.delay_s,
        "delay_fitted": fit.delay_fitted,
        "parameters": dict(zip(fit.names, fit.parameters.tolist(), strict=True)),
        "standard_errors": {name: (e if math.isfinite(e) else None)
                            for name, e in zip(fit.names, fit.standard_errors.tolist(), strict=True)},
        "stable": fit.stable,
        "covariance": fit.covariance.tolist(),
        "modes": [{"natural_frequency_hz": fn, "damping_ratio": zeta} for fn, zeta in fit.modes()],
        "chi2": fit.chi2,
        "dof": fit.dof,
        "bic": fit.bic,
        "residuals": [{"frequency_hz": float(f), "real": float(r.real), "imag": float(r.imag)}
                      for f, r in zip(fit.frequency_hz, fit.residuals, strict=True)],
        "compared": [{"order": list(f.order), "bic": f.bic, "chi2": f.chi2, "stable": f.stable} for f in fits],
    }


def fit_to_mat(fit: TransferFit, channel: str, harmonic: int) -> dict[str, Any]:
    """The fit as MATLAB variables (for ``scipy.io.savemat``): ``G = tf(num, den, 'InputDelay', delay_s)`` is the
    fitted transfer function (s in rad/s, highest power first, the integrator's s multiplied into ``den``);
    ``den_rational`` is ``den`` without it. Also ``integrator`` and ``delay_fitted`` (logical), ``parameter_names``
    (cell of char), ``parameters``, ``standard_errors`` (NaN where the data do not determine one), ``covariance``,
    ``natural_frequency_hz`` and ``damping_ratio`` of each mode, ``frequency_hz`` and ``residuals`` (complex, in
    standard deviations of each point), ``chi2``, ``dof``, ``bic``, ``stable``, ``channel``, ``harmonic``."""
    modes = fit.modes()
    return {
        "num": fit.num.reshape(1, -1),
        "den": (np.polymul(fit.den, [1.0, 0.0]) if fit.integrator else fit.den).reshape(1, -1),
        "den_rational": fit.den.reshape(1, -1),
        "integrator": fit.integrator,
        "delay_s": fit.delay_s,
        "delay_fitted": fit.delay_fitted,
        "parameter_names": np.array(fit.names, dtype=object).reshape(-1, 1),
        "parameters": fit.parameters.reshape(-1, 1),
        "standard_errors": fit.standard_errors.reshape(-1, 1),
        "covariance": fit.covariance,
        "natural_frequency_hz": np.array([fn for fn, _ in modes], dtype=float).reshape(-1, 1),
        "damping_ratio": np.array([zeta for _, zeta in modes], dtype=float).reshape(-1, 1),
        "frequency_hz": np.asarray(fit.frequency_hz, dtype=float).reshape(-1, 1),
        "residuals": np.asarray(fit.residuals, dtype=complex).reshape(-1, 1),
        "chi2": fit.chi2,
        "dof": fit.dof,
        "bic": fit.bic,
        "stable": fit.stable,
        "channel": channel,
        "harmonic": harmonic,
    }


def to_control(fit: TransferFit) -> Any:
    """python-control's ``TransferFunction`` of the rational part (the delay, where fitted, is in ``delay_s``:
    ``control.pade`` approximates it). MissingDependency naming the extra without python-control."""
    from bodebench.drivers.extras import require

    control = require("control", "a fitted transfer function for python-control")

    den = np.concatenate([fit.den, [0.0]]) if fit.integrator else fit.den
    return control.tf(fit.num, den)


def plot_fit(fit: TransferFit, response: np.ndarray, sigma: np.ndarray, stem: Path, title: str = "",
             points: int = 300) -> list[Path]:
    """The measured points (with their 95 % intervals) and the fitted G over them, gain (dB) and phase (degrees),
    and below them each point's residual in standard deviations (real and imaginary parts). Writes
    ``stem``.png; returns the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 8.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax_g, ax_p, ax_r = fig.subplots(3, 1, sharex=True)
    f = fit.frequency_hz
    grid = np.geomspace(f.min(), f.max(), points)
    model = fit.evaluate(grid)
    relative = Q95 * sigma / np.abs(response)
    ax_g.errorbar(f, 20 * np.log10(np.abs(response)), yerr=20 / math.log(10) * relative, fmt="o", ms=4, color="k",
                  label="measured (95 %)")
    ax_g.plot(grid, 20 * np.log10(np.abs(model)), "-", color="tab:blue", label=f"fit, order {fit.order[0]}/"
                                                                                 f"{fit.order[1]}")
    unwrap = np.degrees(np.unwrap(np.angle(model)))
    measured_phase = np.degrees(np.angle(response))
    # the measured phases on the model's branch, point by point
    at = np.interp(np.log(f), np.log(grid), unwrap)
    measured_phase = measured_phase + 360.0 * np.round((at - measured_phase) / 360.0)
    ax_p.errorbar(f, measured_phase, yerr=np.degrees(np.minimum(relative, 1.0)), fmt="o", ms=4, color="k")
    ax_p.plot(grid, unwrap, "-", color="tab:blue")
    ax_r.plot(f, fit.residuals.real, "o", ms=4, color="tab:green", label="real part")
    ax_r.plot(f, fit.residuals.imag, "s", ms=4, mfc="none", color="tab:purple", label="imaginary part")
    for level in (-2.0, 2.0):
        ax_r.axhline(level, color="0.6", lw=0.8, ls="--")
    ax_r.axhline(0.0, color="0.3", lw=0.8)
    ax_g.set_xscale("log")
    ax_g.set_ylabel("Gain (dB)")
    ax_p.set_ylabel("Phase (deg)")
    ax_r.set_ylabel("Residual (sd)")
    ax_r.set_xlabel("Frequency (Hz)")
    ax_g.legend(fontsize="small")
    ax_r.legend(fontsize="small")
    for ax in (ax_g, ax_p, ax_r):
        ax.grid(True, which="both", alpha=0.4)
    if title:
        fig.suptitle(title)
    path = Path(f"{stem}.png")
    fig.savefig(path)
    return [path]
