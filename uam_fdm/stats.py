"""Confidence intervals of episode outcome rates, shared by the learned pilot's evaluation (`rl`) and the
comparison's summaries (`compare`).

Rates (success, collision) get the Wilson score interval, which stays inside [0, 1] and keeps its coverage
for small counts and rates near 0 or 1 (10 successes in 10 episodes: [0.72, 1]).
"""
from __future__ import annotations

import math
from statistics import NormalDist


def z_quantile(probability: float) -> float:
    """The standard normal quantile z_probability (e.g. 0.975 -> 1.95996)."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"a normal quantile needs a probability in (0, 1), got {probability!r}")
    return NormalDist().inv_cdf(probability)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval of a rate: `successes` of `n` trials (n >= 1), two-sided at `confidence`.

    Returns:
        (low, high), inside [0, 1].
    """
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"a rate needs 0 <= successes <= n and n >= 1, got {successes} of {n}")
    z = z_quantile(0.5 + confidence / 2.0)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2.0 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)) / denom
    # exact at the ends: 0 of n has its low end at 0, n of n its high end at 1 (rounding would leave 1e-17)
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return low, high
