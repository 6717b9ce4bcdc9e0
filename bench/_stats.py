"""Rates for the bench tables: a success count out of n with its Wilson score interval."""

from __future__ import annotations


def wilson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval ``(low, high)`` of a success rate ``k / n``, both in [0, 1].

    The Wilson interval rather than the normal approximation because the bench's rates sit near 100 % on
    tens of scenes, where the normal interval overshoots 1 and is too narrow (scipy's ``binomtest``
    computes it). ``n == 0`` carries no information: ``(0.0, 1.0)``. Raises ValueError for k outside 0..n.
    """
    from scipy.stats import binomtest

    k, n = int(k), int(n)
    if n < 0 or not 0 <= k <= max(n, 0):
        raise ValueError(f"wilson_interval: need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    ci = binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def format_rate(k: int, n: int) -> str:
    """``"13/20 = 65 % (43-82 %)"``: the count, the rate and its 95 % Wilson interval, in whole percent."""
    if n == 0:
        return "0/0"
    lo, hi = wilson_interval(k, n)
    return f"{k}/{n} = {100 * k / n:.0f} % ({100 * lo:.0f}-{100 * hi:.0f} %)"
