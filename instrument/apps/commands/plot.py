"""``bodebench plot``: one Bode diagram of several results directories."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

log = logging.getLogger("bodebench")


def _plot(args: argparse.Namespace) -> int:
    from bodebench.apps.plots import plot_comparison
    from bodebench.io.results import CSV_NAME, ResultsError, load_response

    responses = {}
    for given in args.results:
        directory = Path(given)
        if not directory.is_dir():
            raise ResultsError(f"{directory}: not a directory")
        found = [directory] if (directory / CSV_NAME).exists() else sorted(
            p for p in directory.iterdir() if p.is_dir() and (p / CSV_NAME).exists())
        if not found:
            raise ResultsError(f"{directory}: no {CSV_NAME} here or in its sub-directories")
        for sub in found:
            label = given if sub == directory else str(Path(given) / sub.name)
            responses[label] = load_response(sub)
    try:
        path = plot_comparison(responses, Path(args.out), args.title)
    except ValueError as exc:  # names the file where it is the file's fault
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"bodebench: {args.out}: cannot write the plot: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"{len(responses)} responses -> {path}")
    return 0
