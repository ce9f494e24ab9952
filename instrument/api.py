"""The Python interface: sweep from a script or a notebook, load results, hand them to other tools.

A configuration is a TOML file's path, a dict shaped like that file, or an already loaded
:class:`~bodebench.io.config.ExperimentConfig`; it is validated exactly as the command line validates it.
:func:`simulate` and :func:`run` measure one case and return a :class:`Response`; :func:`load` reads a results
directory. A :class:`Response` is a :class:`~bodebench.core.response.FrequencyResponse` with the exporters of
:mod:`bodebench.io.export` as methods.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bodebench.bench.events import Listener
from bodebench.core.response import FrequencyResponse
from bodebench.io import export
from bodebench.io.config import CaseConfig, ExperimentConfig, load_config, parse_config
from bodebench.io.results import load_response

__all__ = ["ConfigSource", "Response", "configure", "load", "run", "simulate"]

ConfigSource = str | Path | Mapping[str, Any] | ExperimentConfig
"""What the sweeps accept as a configuration: a TOML path, a dict shaped like the file, or a loaded config."""


if TYPE_CHECKING:
    from bodebench.core.fit import TransferFit


class Response(FrequencyResponse):
    """A measured frequency response (see :class:`FrequencyResponse`) with its exporters."""

    @classmethod
    def of(cls, response: FrequencyResponse) -> Response:
        """The same points, configuration and case as ``response``."""
        return cls(response.points, config=response.config, case=response.case)

    def to_frd(self, harmonic: int = 1, channel: str | None = None) -> Any:
        """python-control's ``FrequencyResponseData`` of one harmonic and channel; see :func:`export.to_frd`."""
        return export.to_frd(self, harmonic, channel)

    def to_mat(self, path: str | Path) -> Path:
        """Write a MATLAB file (scipy.io); see :func:`export.save_mat` for its variables."""
        return export.save_mat(self, path)

    def to_dataframe(self) -> Any:
        """One pandas row per point; see :func:`export.to_dataframe`."""
        return export.to_dataframe(self)

    def fit(self, order: tuple[int, int] | None = None, *, max_order: int = 4, harmonic: int = 1,
            channel: str | None = None, integrator: bool = False, delay: bool = False) -> TransferFit:
        """A rational transfer function fitted to one harmonic and channel, each point weighted by its interval:
        of ``order`` (numerator, denominator degrees), or the stable order of least BIC up to ``max_order``; see
        :mod:`bodebench.core.fit`. ValueError saying why when there is nothing to fit."""
        from bodebench.analysis.fitting import fit_response

        return fit_response(self, order, max_order=max_order, harmonic=harmonic, channel=channel,
                            integrator=integrator, delay=delay)[0]


def configure(config: ConfigSource) -> ExperimentConfig:
    """Load and validate a configuration (raises :class:`~bodebench.io.config.ConfigError`, one line)."""
    if isinstance(config, ExperimentConfig):
        return config
    if isinstance(config, (str, Path)):
        return load_config(config)
    if isinstance(config, Mapping):
        return parse_config(config, "<dict>")
    raise TypeError(f"config must be a path, a mapping or an ExperimentConfig, got {type(config).__name__}")


def _case_index(config: ExperimentConfig, case: str | None) -> int:
    names = [c.name for c in config.cases]
    if case is None:
        if len(names) > 1:
            raise ValueError(f"{config.path}: {len(names)} cases ({', '.join(names)}); choose one with case=")
        return 0
    if case not in names:
        raise ValueError(f"{config.path}: no case {case!r} (cases: {', '.join(names)})")
    return names.index(case)


def _procedure(config: ExperimentConfig, index: int, out: Path, *, direct: bool, resume: bool, plots: bool,
               listener: Listener | None, jobs: int | None, samples: bool = True) -> Response:
    from bodebench.bench.offline import offline_executor
    from bodebench.bench.procedure import SweepProcedure

    writer = None
    if plots:
        from bodebench.apps.plots import write_plots

        writer = write_plots
    case = config.cases[index]
    with offline_executor(1 if case.bench is not None else jobs, models=_models(case)) as executor:
        procedure = SweepProcedure(config, out, listener=listener, direct=direct, plots=writer, executor=executor,
                                   existing="resume" if resume else "refuse", keep_samples=samples)
        outcome = procedure.run(cases=[index])[0]
    return Response.of(outcome.response)


def _models(case: CaseConfig) -> tuple[str, ...]:
    """The plant model whose compiled step loops an offline pool loads first (none without a plant)."""
    return (case.plant.model,) if case.plant is not None and case.bench is None else ()


def _check_jobs(jobs: int | None) -> None:
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise ValueError(f"jobs must be an integer >= 1 or None (all cores), got {jobs!r}")


def simulate(config: ConfigSource, out: str | Path | None = None, *, case: str | None = None, jobs: int | None = 1,
             resume: bool = False, plots: bool = False, samples: bool = False,
             listener: Listener | None = None) -> Response:
    """Sweep one case offline: the simulated plant of an experiment config, or a bench config's simulated drive
    called in-process without a bus (as ``bodebench simulate``).

    out: results directory (None: nothing is written); case: the case's name (needed when the file has several);
    jobs: worker processes for the frequencies of an offline experiment (1: this process, None: every core);
    resume: continue an interrupted sweep in ``out``; plots: draw bode/periods plots into ``out``; samples: keep
    each frequency's raw samples in ``out/samples/`` (a simulation's are reproducible from its config); listener: gets
    the events of :mod:`bodebench.bench.events`. Raises ConfigError, ResultsError (``out`` holds another sweep),
    SessionError (a bench sweep stopped; its points so far are in ``out``)."""
    _check_jobs(jobs)
    experiment = configure(config)
    index = _case_index(experiment, case)
    chosen: CaseConfig = experiment.cases[index]
    if out is None and chosen.bench is None and listener is None:
        from bodebench.bench.offline import offline_executor, sweep

        with offline_executor(jobs, models=_models(chosen)) as executor:
            return Response.of(sweep(chosen, executor))
    if out is None:
        with tempfile.TemporaryDirectory(prefix="bodebench-") as scratch:
            return _procedure(experiment, index, Path(scratch), direct=True, resume=False, plots=False,
                              listener=listener, jobs=jobs, samples=False)
    return _procedure(experiment, index, Path(out), direct=True, resume=resume, plots=plots, listener=listener,
                      jobs=jobs, samples=samples)


def run(config: ConfigSource, out: str | Path, *, case: str | None = None, resume: bool = False,
        plots: bool = False, listener: Listener | None = None) -> Response:
    """Sweep one case of a bench config on its drive, over CAN or serial (as ``bodebench run``): a ``[simulator]``
    table starts the simulated drive on its bus, otherwise the real drive is measured.

    Each point is on disk in ``out`` the moment it is measured. Arguments as :func:`simulate`. Raises ConfigError
    (not a bench config), ResultsError, SessionError (the sweep stopped: the drive was left at zero; the points
    measured so far are in ``out``), DriverError (the bus or port cannot be opened)."""
    experiment = configure(config)
    index = _case_index(experiment, case)
    if experiment.cases[index].bench is None:
        from bodebench.io.schema import ConfigError

        raise ConfigError(f"{experiment.path}: bench: missing (run sweeps a drive; simulate() sweeps an "
                          "offline experiment)", "bench")
    return _procedure(experiment, index, Path(out), direct=False, resume=resume, plots=plots, listener=listener,
                      jobs=1)


def load(directory: str | Path) -> Response:
    """The response saved in a results directory (``response.csv`` and ``response.json``); raises ResultsError."""
    return Response.of(load_response(directory))
