"""Suite-wide collection order."""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Whole sweeps (marked ``slow``) first, each group in its own order: spread over workers (``pytest -n 2``),
    the long tests start early and the short ones fill in around them, so no worker ends alone on a long one."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
