"""The results directories the terminal UI reads and writes: the cases' earlier results, the responses to
overlay, a case's points saved with their summary and plots."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bodebench.bench.procedure import case_directory, previous_run
from bodebench.bench.session import completed_frequencies
from bodebench.core.response import FrequencyResponse
from bodebench.core.summary import summarize_response
from bodebench.io.config import CaseConfig, ExperimentConfig
from bodebench.io.results import (
    CSV_NAME,
    ResultsError,
    load_response,
    save_response,
    sidecar_runs,
    update_sidecar,
)


def load_results(path: Path) -> list[tuple[str, FrequencyResponse]]:
    """Responses in ``path`` (a results directory, or a directory of them): [(label, response)].
    Raises ResultsError naming the path when there is none or a file is bad."""
    if not path.is_dir():
        raise ResultsError(f"{path}: not a directory")
    if (path / CSV_NAME).exists():
        response = load_response(path)
        return [(response.case or path.name, response)]
    found = []
    for sub in sorted(p for p in path.iterdir() if p.is_dir() and (p / CSV_NAME).exists()):
        response = load_response(sub)
        found.append((f"{path.name}/{sub.name}", response))
    if not found:
        raise ResultsError(f"{path}: no {CSV_NAME} here or in its sub-directories")
    return found


def load_cases(config: ExperimentConfig, out: Path) -> tuple[dict[int, FrequencyResponse], list[str]]:
    """The results already under ``out`` of each case of ``config`` that has them ({case index: response}), and
    a line on each directory that could not be read."""
    results: dict[int, FrequencyResponse] = {}
    problems: list[str] = []
    for i, case in enumerate(config.cases):
        directory = case_directory(config, out, case)
        if not (directory / CSV_NAME).exists():
            continue
        try:
            results[i] = load_response(directory)
        except ResultsError as exc:
            problems.append(str(exc))
    return results, problems


@dataclass
class EarlierResults:
    """What a new sweep of every case would find under its out directory: ``found`` names each case directory
    holding results (and how far a resumable one got), ``resumable`` the sweeps a new one can continue
    ({case index: their points}), ``refused`` why some cannot be continued (empty: all can)."""

    found: list[str] = field(default_factory=list)
    resumable: dict[int, FrequencyResponse] = field(default_factory=dict)
    refused: str = ""


def earlier_results(config: ExperimentConfig, out: Path) -> EarlierResults:
    """The results a sweep of every case of ``config`` into ``out`` would replace or continue."""
    earlier = EarlierResults()
    for i, case in enumerate(config.cases):
        directory = case_directory(config, out, case)
        if not (directory / CSV_NAME).exists():
            continue
        try:
            previous = previous_run(directory, case, "resume")
        except ResultsError as exc:  # another configuration's, or unreadable: to be replaced, not continued
            earlier.found.append(str(directory))
            earlier.refused = earlier.refused or str(exc)
            continue
        if previous is not None:
            earlier.resumable[i] = previous
            done = completed_frequencies(previous, case.analysed_channels, case.analysis.harmonics)
            earlier.found.append(f"{directory} ({len(done)} of {len(case.excitation.frequencies_hz)} frequencies "
                                 "measured)")
    return earlier


def save_case(config: ExperimentConfig, case: CaseConfig, response: FrequencyResponse, directory: Path) -> list[Path]:
    """Write ``response`` (the points of ``case``) to ``directory`` with its summary and plots, keeping the
    records of the runs that made them; returns the plot files."""
    from bodebench.apps.plots import write_plots

    runs = sidecar_runs(directory)
    save_response(response, directory)
    summary = summarize_response(response, case.analysis.response_kind)
    update_sidecar(directory, {"summary": [s.to_json() for s in summary], "runs": runs})
    title = f"{config.title}: {case.name}" if config.has_cases else config.title
    return write_plots(response, directory, title, summary=summary)
