"""Binomial confidence intervals of the observability fractions |K^max|/K and |K^Stan|/K.

The fractions of Sec. IV count trajectories out of K: with K = 40 a fraction is known to
about +-0.15 only, so every table and figure shows it with its exact (Clopper-Pearson)
95 % interval, the beta quantiles

    lower = B^{-1}(alpha/2; x, K - x + 1)      (0 for x = 0)
    upper = B^{-1}(1 - alpha/2; x + 1, K - x)  (1 for x = K)

for x of K trajectories, alpha = 1 - level (as scipy.stats.binomtest(x, K).proportion_ci()).
"""

from __future__ import annotations

import math


def clopper_pearson(successes: float, trials: float, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval of a binomial proportion x / K at ``level``.

    NaN for both ends when either count is missing (NaN) or ``trials`` is 0.  Raises
    ValueError for counts that are not whole numbers with 0 <= x <= K, or a level outside (0, 1).
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    x, n = float(successes), float(trials)
    if math.isnan(x) or math.isnan(n) or n == 0:
        return math.nan, math.nan
    if x != round(x) or n != round(n) or not 0 <= x <= n:
        raise ValueError(
            f"need whole counts 0 <= successes <= trials, got {successes!r} of {trials!r}"
        )
    alpha = 1.0 - level
    from scipy import stats  # here: the Snakefile imports this module, and stats costs 0.5 s

    lower = 0.0 if x == 0 else float(stats.beta.ppf(alpha / 2, x, n - x + 1))
    upper = 1.0 if x == n else float(stats.beta.ppf(1 - alpha / 2, x + 1, n - x))
    return lower, upper


def format_fraction(successes: float, trials: float, digits: int = 2) -> str:
    """``"0.85 [0.70, 0.94]"``: the fraction x / K and its 95 % interval; ``""`` if missing."""
    lower, upper = clopper_pearson(successes, trials)
    if math.isnan(lower):
        return ""
    frac = float(successes) / float(trials)
    return f"{frac:.{digits}f} [{lower:.{digits}f}, {upper:.{digits}f}]"
