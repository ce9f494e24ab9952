"""Stopping rules of monoharmonic autointegration (docs/METHOD.md section 1).

A rule looks at the per-period Fourier coefficients of one series (one channel, one harmonic), held as complex
numbers ``Z(i) = P(i) + j Q(i)``, and decides after period ``n`` whether the point is measured and what its value
is. The paper's rules are implemented exactly as printed; ``adaptive`` is the default, built to deliver the
requested error (see docs/measurement.md, "Stopping rules" section for the evidence).

Reading map, in reading order:

- :mod:`.rule`: what every rule is: :class:`StoppingRule`, its :class:`Verdict`, the statuses and the tolerance.
  Read it first.
- :mod:`.history`: :class:`SeriesHistory`, the coefficients of one series and the running sums every rule
  reads.
- :mod:`.printed`: the paper's rules as printed and the fixed schemes.
- :mod:`.adaptive`: :class:`AdaptiveRule`, the default. Its decision is :meth:`AdaptiveRule.check`, written
  once there: the settled estimate's verdict, else the modal fit's.
- :mod:`.intervals`: the settled estimate (the first estimator) and the interval factors; the named inequalities
  by which it is accepted.
- :mod:`.modal`: the modal fit and forecast (the second estimator) and the bound by which two windows' fits
  confirm a limit; :mod:`.least_squares`, the fit's solve by LAPACK.
- :mod:`.criteria`: the criterion names a config may give and :func:`make_rule`.

Only speed, never a verdict: :mod:`.screens`, necessary conditions from the running sums (one period at a time
or a table of many at once) under which the analysis of a period could give a verdict. A screen calls the same
named inequalities as the decision, or says in its docstring which of them it bounds.

Part of the decision, though it looks like speed: the fit's schedule in :mod:`.adaptive` (fits spaced out once
windows are long, put off for a slowly decaying mode). The modal fit is judged only at the periods the schedule
gives, so a fit at every period would stop at other periods with other values.

Check mode: with the environment variable ``BODEBENCH_CHECK_SCREENS=1`` (read once, when :mod:`.adaptive` is
imported) every :class:`AdaptiveRule` also runs the full, unscreened analysis wherever a screen spared one, and
raises AssertionError, naming the period and the screen, where that analysis gives a verdict. The whole suite in
that mode: ``BODEBENCH_CHECK_SCREENS=1 python -m pytest -n 2 -q``.
"""

from bodebench.core.rules.adaptive import AdaptiveRule
from bodebench.core.rules.criteria import CRITERIA, make_rule
from bodebench.core.rules.history import SeriesHistory
from bodebench.core.rules.intervals import CONFIDENCE, MIN_NOISE_EVIDENCE, Estimate, settled_estimate
from bodebench.core.rules.modal import ModalFit, extrapolate_modes
from bodebench.core.rules.printed import (
    Combined1,
    Combined2,
    Combined3,
    FixedScheme,
    FullAveraging,
    LocalAveraging,
    NoAveraging,
    relative_change_percent,
)
from bodebench.core.rules.rule import (
    BELOW_RESOLUTION,
    CAPPED,
    CONVERGED,
    FIXED,
    NOISE_LIMITED,
    RESOLUTION,
    StoppingRule,
    Verdict,
)

__all__ = [
    "BELOW_RESOLUTION", "CAPPED", "CONFIDENCE", "CONVERGED", "CRITERIA", "FIXED", "MIN_NOISE_EVIDENCE",
    "NOISE_LIMITED", "RESOLUTION", "AdaptiveRule", "Combined1", "Combined2", "Combined3", "Estimate", "FixedScheme",
    "FullAveraging", "LocalAveraging", "ModalFit", "NoAveraging", "SeriesHistory", "StoppingRule", "Verdict",
    "extrapolate_modes", "make_rule", "relative_change_percent", "settled_estimate",
]
