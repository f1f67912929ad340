"""χ² quantile, CDF and survival function without importing ``scipy.stats`` (issue 23: start-up).

``scipy.stats`` takes about 0.5 s to import (its distributions build their
docstrings at import), and the filters need only three numbers of the χ²
law, once per configuration. These are the very functions
``scipy.stats.chi2`` evaluates (``_ppf = 2 gammaincinv(df/2, q)``,
``_cdf = chdtr(df, x)``, ``_sf = chdtrc(df, x)``, with ``loc = 0`` and
``scale = 1``, which add and multiply exactly), so the values are the same
floats (``test/test_chi2.py`` compares them); ``scipy.special`` is imported
on the first call.
"""

from __future__ import annotations

import math

__all__ = ["chi2_ppf", "chi2_cdf", "chi2_sf"]


def _check(df: float) -> float:
    d = float(df)
    if not (math.isfinite(d) and d > 0.0):
        raise ValueError(f"degrees of freedom must be finite and > 0, got {df!r}")
    return d


def chi2_ppf(q: float, df: float) -> float:
    """The χ²_df quantile of probability ``q`` in (0, 1) (``scipy.stats.chi2.ppf(q, df)``).

    Raises:
        ValueError: ``q`` outside (0, 1) or ``df`` not finite and > 0.
    """
    from scipy.special import gammaincinv

    if not (0.0 < q < 1.0):
        raise ValueError(f"probability must be in (0, 1), got {q!r}")
    return float(2 * gammaincinv(_check(df) / 2, q))


def chi2_cdf(x: float, df: float) -> float:
    """``P(X ≤ x)`` for ``X ~ χ²_df``, ``x ≥ 0`` (``scipy.stats.chi2.cdf(x, df)``)."""
    from scipy.special import chdtr

    return float(chdtr(_check(df), x))


def chi2_sf(x: float, df: float) -> float:
    """``P(X > x)`` for ``X ~ χ²_df``, ``x ≥ 0`` (``scipy.stats.chi2.sf(x, df)``)."""
    from scipy.special import chdtrc

    return float(chdtrc(_check(df), x))
