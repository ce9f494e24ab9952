"""``bodebench identify``: dry friction and mass of the friction link from a measured response."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from bodebench.apps.commands.common import _chain_taken_off

log = logging.getLogger("bodebench")


def _identify(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from bodebench.analysis.calibration import CalibrationError, load_calibration
    from bodebench.analysis.identify import IdentificationError, format_report, identify, plot_identification
    from bodebench.io.results import load_response

    directory = Path(args.results)
    response = _chain_taken_off(load_response(directory), args, directory)
    try:
        report = identify(response, args.stiffness, args.amplitude, harmonic=args.harmonic, channel=args.channel,
                          fit_stiffness=args.fit_stiffness, fit_damping=args.fit_damping,
                          table=load_calibration(args.calibration))
    except (IdentificationError, CalibrationError) as exc:
        print(f"bodebench: {directory}: {exc}", file=sys.stderr)
        return 2
    status = 0
    if not args.no_plot:
        try:
            paths = plot_identification(response, report, directory / "identify")
            report = dataclasses.replace(report, plots=tuple(str(p) for p in paths))
        except OSError as exc:
            print(f"bodebench: {directory}: cannot write the identification plot: {exc}", file=sys.stderr)
            status = 1
    print(json.dumps(report.to_json(), indent=2, allow_nan=False) if args.json else format_report(report))
    return status
