"""``bodebench dbc``: a bench configuration's frames as a DBC file."""

from __future__ import annotations

import argparse
import logging

from bodebench.apps.commands.common import _load, _write_new

log = logging.getLogger("bodebench")


def _dbc(args: argparse.Namespace) -> int:
    from bodebench.drivers.dbc import layout_database
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (an offline experiment has no frames to describe)", "bench")
    texts: dict[str, list[str]] = {}
    for case in config.cases:
        layout = case.on_bench.layout
        texts.setdefault(layout_database(layout, f"bodebench frame layout of {args.config}").as_dbc_string(),
                         []).append(case.name)
    if len(texts) > 1:
        groups = "; ".join(", ".join(names) for names in texts.values())
        raise ConfigError(f"{args.config}: frames: the cases have different frame layouts ({groups}): write each "
                          "from a configuration of its own", "frames")
    _write_new(next(iter(texts)), args.out, "frame layout")
    return 0
