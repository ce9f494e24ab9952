"""A measured response in the formats of other tools: python-control, MATLAB (via scipy.io) and pandas.

Each exporter takes a :class:`~bodebench.core.response.FrequencyResponse` and imports its library only when called,
so none of them is a dependency of bodebench. The complex response of a point is ``(p + i q) / amplitude``: its
magnitude is the gain (output units per input unit) and its angle the phase, so that a point of harmonic ``k`` is
``G_k(f)``, the k-th harmonic of the output relative to the input's fundamental at the excitation frequency ``f``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bodebench.core.response import FrequencyResponse
from bodebench.drivers.extras import MissingDependency, require

__all__ = ["MAT_COLUMNS", "MissingDependency", "mat_arrays", "save_mat", "to_dataframe", "to_frd"]


#: Per-point columns of :func:`mat_arrays` and :func:`to_dataframe`, in order.
MAT_COLUMNS: tuple[str, ...] = (
    "frequency_hz", "harmonic", "channel", "amplitude", "p", "q", "gain", "gain_db", "phase_deg", "uncertainty",
    "uncertainty_1d", "gain_ci", "gain_db_ci", "phase_ci_deg", "periods", "converged", "within_eps",
    "periods_needed", "periods_discarded", "thd", "coherence", "drift_per_s", "status",
)


def _series(response: FrequencyResponse, harmonic: int, channel: str | None) -> FrequencyResponse:
    """The points of one harmonic and channel (default: the first channel), sorted by frequency."""
    if channel is None:
        if not response.channels:
            raise ValueError("the response holds no points")
        channel = response.channels[0]
    chosen = response.select(harmonic=harmonic, channel=channel)
    if not chosen.points:
        raise ValueError(f"no points of harmonic {harmonic} on channel {channel!r} (the response has harmonics "
                         f"{response.harmonics} and channels {response.channels})")
    freqs = chosen.frequency_hz
    if np.any(np.diff(freqs) <= 0.0):
        raise ValueError(f"harmonic {harmonic} on channel {channel!r} has a frequency measured twice")
    return chosen


def to_frd(response: FrequencyResponse, harmonic: int = 1, channel: str | None = None) -> Any:
    """python-control's ``FrequencyResponseData`` of one harmonic and channel (default: the first channel).

    Frequencies are the excitation's, as angular frequencies (rad/s), in ascending order; the data are the complex
    responses. Each point's interval goes with them as attributes of the object, in the same order:
    ``interval_95`` the 95 % half-width of the complex response along one direction (relative to the input
    amplitude, the response's units), ``gain_ci`` and ``phase_ci_deg`` the 95 % half-widths of the gain (per unit
    input) and of the phase (degrees), ``converged`` and ``status`` each point's verdict. Raises
    :class:`MissingDependency` without python-control, ValueError for an empty selection."""
    control = require("control", "to_frd")
    chosen = _series(response, harmonic, channel)
    name = f"{chosen.case or 'response'}:{chosen.points[0].channel}:h{harmonic}"
    system = control.frd(chosen.complex_response(), 2.0 * np.pi * chosen.frequency_hz, name=name)
    half = np.array([p.uncertainty_1d if np.isfinite(p.uncertainty_1d) else p.uncertainty for p in chosen.points])
    system.interval_95 = half / np.array([p.amplitude for p in chosen.points])
    system.gain_ci = np.array([p.gain_ci for p in chosen.points])
    system.phase_ci_deg = np.array([p.phase_ci_deg for p in chosen.points])
    system.converged = np.array([p.converged for p in chosen.points])
    system.status = [str(p.status) for p in chosen.points]
    return system


def _column(response: FrequencyResponse, name: str) -> np.ndarray:
    values = [getattr(point, name) for point in response.points]
    if name in ("channel", "status"):
        return np.array([str(v) for v in values], dtype=object)  # plain str: a str enum would become a struct
    if name in ("harmonic", "periods", "periods_needed", "periods_discarded"):
        return np.array(values, dtype=np.int64)
    if name in ("converged", "within_eps"):
        return np.array(values, dtype=bool)
    return np.array(values, dtype=float)


def mat_arrays(response: FrequencyResponse) -> dict[str, Any]:
    """The variables :func:`save_mat` writes (see there), as numpy arrays and nested dicts."""
    out: dict[str, Any] = {name: _column(response, name) for name in MAT_COLUMNS}
    out["response"] = response.complex_response()
    series: dict[str, Any] = {}
    for channel in response.channels:
        for harmonic in response.harmonics:
            chosen = response.select(harmonic=harmonic, channel=channel)
            if chosen.points:
                series[f"{channel}_h{harmonic}"] = {
                    "frequency_hz": chosen.frequency_hz,
                    "response": chosen.complex_response(),
                    "gain": chosen.gain,
                    "phase_deg": chosen.phase_deg,
                    "gain_ci": _column(chosen, "gain_ci"),
                    "phase_ci_deg": chosen.phase_ci_deg,
                    "status": _column(chosen, "status"),
                }
    out["series"] = series
    out["case"] = response.case
    return out


def save_mat(response: FrequencyResponse, path: str | Path) -> Path:
    """Write ``response`` to a MATLAB file (``scipy.io.savemat``, format 5); returns the path.

    Per point (column vectors in measurement order): ``frequency_hz``, ``harmonic``, ``channel`` and ``status``
    (cell arrays of char), ``amplitude``, ``p``, ``q``, ``response`` (complex), ``gain``, ``gain_db``,
    ``phase_deg``, the 95 % figures ``uncertainty``, ``uncertainty_1d``, ``gain_ci``, ``gain_db_ci``,
    ``phase_ci_deg``, and ``periods``, ``converged``, ``within_eps``, ``periods_needed``, ``periods_discarded``,
    ``thd``, ``coherence``. ``series.<channel>_h<k>``
    is a struct per channel and harmonic, sorted by frequency: ``frequency_hz``, ``response``, ``gain``,
    ``phase_deg``, ``gain_ci``, ``phase_ci_deg``, ``status``. ``case`` names the case."""
    import scipy.io as sio
    path = Path(path)
    sio.savemat(str(path), mat_arrays(response), oned_as="column", do_compression=True)
    return path


def to_dataframe(response: FrequencyResponse) -> Any:
    """A pandas ``DataFrame`` with one row per point (columns :data:`MAT_COLUMNS` and the complex ``response``).
    Raises :class:`MissingDependency` without pandas."""
    pandas = require("pandas", "to_dataframe")
    data = {name: _column(response, name) for name in MAT_COLUMNS}
    data["response"] = response.complex_response()
    return pandas.DataFrame(data)
