"""``bodebench check``: a configuration validated and its plan printed, no bus opened."""

from __future__ import annotations

import argparse
import logging

from bodebench.apps.commands.common import _load

log = logging.getLogger("bodebench")


def _check(args: argparse.Namespace) -> int:
    from bodebench.apps.check import check_lines

    for line in check_lines(_load(args)):
        print(line)
    return 0
