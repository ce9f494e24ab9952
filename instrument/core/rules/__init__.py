"""Stopping rules of monoharmonic autointegration (docs/METHOD.md section 1)."""

from bodebench.core.rules.adaptive import (
    BELOW_RESOLUTION,
    CAPPED,
    CONFIDENCE,
    CONVERGED,
    CRITERIA,
    FIXED,
    MIN_NOISE_EVIDENCE,
    NOISE_LIMITED,
    RESOLUTION,
    AdaptiveRule,
    Combined1,
    Combined2,
    Combined3,
    Estimate,
    FixedScheme,
    FullAveraging,
    LocalAveraging,
    ModalFit,
    NoAveraging,
    SeriesHistory,
    StoppingRule,
    Verdict,
    extrapolate_modes,
    make_rule,
    relative_change_percent,
    settled_estimate,
)

__all__ = [
    "BELOW_RESOLUTION", "CAPPED", "CONFIDENCE", "CONVERGED", "CRITERIA", "FIXED", "MIN_NOISE_EVIDENCE",
    "NOISE_LIMITED", "RESOLUTION", "AdaptiveRule", "Combined1", "Combined2", "Combined3", "Estimate", "FixedScheme",
    "FullAveraging", "LocalAveraging", "ModalFit", "NoAveraging", "SeriesHistory", "StoppingRule", "Verdict",
    "extrapolate_modes", "make_rule", "relative_change_percent", "settled_estimate",
]
