"""``bodebench run`` and ``bodebench tui``: a sweep of the drive on the bench, headless or in the terminal UI."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from bodebench.apps.commands.common import _bench_sweeps, _existing, _load, _plot_writer

log = logging.getLogger("bodebench")


def _run(args: argparse.Namespace) -> int:
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (bodebench run needs a bench config; "
                          "use bodebench simulate for an offline experiment)", "bench")
    return _bench_sweeps(config, Path(args.out), direct=False, quiet=args.quiet, existing=_existing(args),
                         plots=_plot_writer(args), log_bus=_log_bus(args.log_bus),
                         keep_samples=not args.no_samples)


def _log_bus(value: str | None) -> Path | None:
    """The --log-bus file, checked before anything is sent; its directory is made where it does not exist (as
    ``--out`` makes the results directory)."""
    from bodebench.io.results import ResultsError

    if value is None:
        return None
    path = Path(value)
    if path.is_dir():
        raise ResultsError(f"--log-bus {value}: is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResultsError(f"--log-bus {value}: cannot make its directory {path.parent}: {exc.strerror}") from None
    return path


def _tui(args: argparse.Namespace) -> int:
    from bodebench.apps.tui import run_tui
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (bodebench tui needs a bench config)", "bench")
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    return run_tui(config, out, log_bus=_log_bus(args.log_bus))
