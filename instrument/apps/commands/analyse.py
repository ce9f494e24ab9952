"""``bodebench analyse``: a sweep recomputed from its raw samples."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from bodebench.apps.commands.common import _chain_taken_off, _print_summary

log = logging.getLogger("bodebench")


def _analyse(args: argparse.Namespace) -> int:
    from bodebench.analysis.reanalyse import reanalyse
    from bodebench.io.results import CSV_NAME, ResultsError, load_response, save_response, verify_results
    from bodebench.io.samples import SamplesError

    directory = Path(args.results)
    overrides: dict[str, object] = {}
    if args.criterion is not None:
        overrides["criterion"] = args.criterion
    if args.tolerance is not None:
        overrides["tolerance_percent"] = args.tolerance
    out = Path(args.out) if args.out else None
    if out is not None and (out / CSV_NAME).exists():
        raise ResultsError(f"{out / CSV_NAME}: results already here; choose another --out")
    try:
        result = reanalyse(directory, **overrides)
    except SamplesError as exc:
        print(f"bodebench: {exc} (a sweep keeps its samples since bodebench 0.1; measure it again)",
              file=sys.stderr)
        return 2
    stored = load_response(directory)
    checked, changed = verify_results(directory)
    for line in changed:  # what changed since it was written, by the checksums recorded then
        print(f"{directory}: {line}")
    if not checked:
        print(f"{directory}: made without checksums: what was edited since cannot be told")
    response, analysis = _chain_taken_off(result.response, args, directory), result.analysis
    if args.without_chain:
        stored = _chain_taken_off(stored, args, directory)
    again = {(p.frequency_hz, p.harmonic, p.channel): p for p in response.points}
    differ = [(a, again.get((a.frequency_hz, a.harmonic, a.channel))) for a in stored.points
              if not any(f == a.frequency_hz for f, _ in result.failed)]
    differ = [(a, b) for a, b in differ if b is None or not _same_point(a, b)]
    same = len(stored.points) - len(differ) - sum(1 for a in stored.points
                                                  if any(f == a.frequency_hz for f, _ in result.failed))
    print(f"{directory}: {len(response)} points from their samples, criterion {analysis.criterion}, tolerance "
          f"{analysis.tolerance_percent:g} %; {same} identical to the stored points"
          + (f", {len(differ)} not:" if differ else ""))
    for a, b in differ:  # each one named, with by how much
        where = f"  {a.frequency_hz:g} Hz harmonic {a.harmonic} {a.channel}"
        if b is None:
            print(f"{where}: stored, not found again")
        else:
            change = abs(complex(b.p, b.q) - complex(a.p, a.q)) / max(abs(complex(a.p, a.q)), 1e-300)
            print(f"{where}: stored {a.gain_db:.6g} dB {a.phase_deg:.6g} deg {a.status}, again {b.gain_db:.6g} dB "
                  f"{b.phase_deg:.6g} deg {b.status} (|dZ|/|Z| = {change:.3g})")
    if not args.quiet:
        print(f"{'f Hz':>10} {'k':>2} {'channel':<14} {'gain dB':>11} {'phase deg':>10} {'periods':>7}  status")
        for p in response.points:
            print(f"{p.frequency_hz:10g} {p.harmonic:2d} {p.channel:<14} {p.gain_db:11.5f} {p.phase_deg:10.4f} "
                  f"{p.periods:7d}  {p.status}")
    if not args.quiet:
        from bodebench.core.summary import summarize_response

        if args.without_chain:
            print(f"the bench's hold and a delay of {args.delay:g} s taken off every phase (--without-chain):")
        print(f"{response.case}:")
        _print_summary(summarize_response(response, analysis.response_kind))
    for f, why in result.failed:
        print(f"{f:g} Hz left out, too many periods with gaps: {why}")
    if result.record_ended:
        print(f"the record ended before the rule stopped at {len(result.record_ended)} frequencies (capped there): "
              + ", ".join(f"{f:g}" for f in result.record_ended) + " Hz")
    if out is not None:
        from bodebench.apps.plots import write_plots

        save_response(response, out)
        files = write_plots(response, out, f"{response.case} ({analysis.criterion}, {analysis.tolerance_percent:g} %)",
                            formats=args.plots)
        print(f"-> {out / CSV_NAME} (+ {', '.join(f.name for f in files)})")
    return 0


class _NotRaised(Exception):
    """Stands for an error class not yet imported when start-up is interrupted (nothing raises it)."""


def _same_point(a: object, b: object) -> bool:
    """Whether two points are the same, bit for bit (NaN equal to NaN)."""
    import dataclasses
    import math

    assert dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b)
    for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b), strict=True):  # type: ignore[arg-type]
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            continue
        if x != y:
            return False
    return True
