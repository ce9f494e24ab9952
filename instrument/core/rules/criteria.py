"""The criteria a config's ``analysis.criterion`` may name, and :func:`make_rule`, which makes the rule of one.

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

from bodebench.core.rules.adaptive import AdaptiveRule
from bodebench.core.rules.printed import (
    Combined1,
    Combined2,
    Combined3,
    FixedScheme,
    FullAveraging,
    LocalAveraging,
    NoAveraging,
    _PrintedRule,
)
from bodebench.core.rules.rule import StoppingRule

CRITERIA: tuple[str, ...] = (
    "adaptive",
    "full",
    "none",
    "local",
    "combined1",
    "combined2",
    "combined3",
    "first_period",
    "sixth_of_six",
    "fixed",
)


def make_rule(criterion: str, *, tolerance_percent: float, skip_periods: int, window: int,
              settle_periods: int = 50, average_periods: int = 50, max_periods: int = 20000) -> StoppingRule:
    """The rule a config's ``analysis.criterion`` names (a fresh object per series: rules keep state)."""
    if criterion == "adaptive":
        return AdaptiveRule(tolerance_percent, skip_periods, max_periods=max_periods)
    if criterion == "first_period":
        return FixedScheme(0, 1, "first_period", tolerance_percent)
    if criterion == "sixth_of_six":
        return FixedScheme(5, 1, "sixth_of_six", tolerance_percent)
    if criterion == "fixed":
        return FixedScheme(settle_periods, average_periods, "fixed", tolerance_percent)
    printed: dict[str, type[_PrintedRule]] = {
        "none": NoAveraging, "local": LocalAveraging, "full": FullAveraging,
        "combined1": Combined1, "combined2": Combined2, "combined3": Combined3,
    }
    try:
        return printed[criterion](tolerance_percent, skip_periods, window)
    except KeyError:
        raise ValueError(f"unknown criterion {criterion!r}; one of {', '.join(CRITERIA)}") from None
