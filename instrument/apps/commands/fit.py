"""``bodebench fit``: a rational transfer function fitted to a measured response, weighted by each point's
interval."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bodebench.apps.commands.common import _ArgumentError, _chain_taken_off

FIT_NAME = "fit.json"
"""Where ``bodebench fit`` writes its result, beside the response."""
FIT_MAT_NAME = "fit.mat"
"""The same result as MATLAB variables (:func:`~bodebench.analysis.fitting.fit_to_mat`)."""


def _order(text: str) -> tuple[int, int]:
    """``--order NUM/DEN``: the numerator and denominator degrees."""
    head, sep, tail = text.partition("/")
    try:
        order = (int(head), int(tail)) if sep else (0, int(head))
    except ValueError:
        raise _ArgumentError(f"--order {text}: expected NUM/DEN, for example 0/2") from None
    if order[0] < 0 or order[1] < 1 or order[0] > order[1]:
        raise _ArgumentError(f"--order {text}: need 0 <= NUM <= DEN and DEN >= 1")
    return order


def _fit(args: argparse.Namespace) -> int:
    import io
    import json

    import scipy.io as sio

    from bodebench.analysis.fitting import fit_data, fit_lines, fit_response, fit_to_json, fit_to_mat, plot_fit
    from bodebench.io.results import ResultsError, atomic_write_bytes, load_response

    directory = Path(args.results)
    response = _chain_taken_off(load_response(directory), args, directory)
    try:
        fit, fits, channel = fit_response(response, _order(args.order) if args.order else None,
                                          max_order=args.max_order, harmonic=args.harmonic, channel=args.channel,
                                          integrator=args.integrator, delay=args.fit_delay)
    except ValueError as exc:
        print(f"bodebench: {directory}: {exc}", file=sys.stderr)
        return 2
    data = fit_to_json(fit, fits, channel, args.harmonic)
    mat = io.BytesIO()
    sio.savemat(mat, fit_to_mat(fit, channel, args.harmonic), oned_as="column")
    for name, content in ((FIT_NAME, (json.dumps(data, indent=2, allow_nan=False) + "\n").encode("utf-8")),
                          (FIT_MAT_NAME, mat.getvalue())):
        try:
            atomic_write_bytes(directory / name, content)
        except OSError as exc:
            raise ResultsError(f"{directory / name}: cannot write: {exc.strerror or exc}") from None
    status = 0
    if not args.no_plot:
        _, h, sd, _ = fit_data(response, args.harmonic, channel)
        try:
            plot_fit(fit, h, sd, directory / "fit", title=f"{response.case or directory.name}: {channel}")
        except OSError as exc:
            print(f"bodebench: {directory}: cannot write the fit's plot: {exc.strerror or exc}", file=sys.stderr)
            status = 1
    print(json.dumps(data, indent=2, allow_nan=False) if args.json else "\n".join(fit_lines(fit, fits, channel)))
    return status
