"""``bodebench example``: the shipped example configurations."""

from __future__ import annotations

import argparse
import logging

from bodebench.apps.commands.common import _ArgumentError, _write_new

log = logging.getLogger("bodebench")


def _example(args: argparse.Namespace) -> int:
    from bodebench.io.examples import ExampleError, example, examples

    if args.name is None:
        every = examples()
        width = max(len(e.name) for e in every)
        for item in every:
            print(f"{item.name:<{width}}  {item.line}")
        return 0
    try:
        item = example(args.name)
    except ExampleError as exc:
        raise _ArgumentError(str(exc)) from None
    _write_new(item.text(), args.out, f"example {item.name}")
    return 0
