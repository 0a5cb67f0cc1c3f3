"""The interval and power arithmetic of the summary, as plain functions of counts and samples.

Rates (success, collision) get the Wilson score interval, which stays inside [0, 1] and keeps its
coverage for small counts and rates near 0 or 1, where the bootstrap of a 0/1 sample collapses to a
point (10 successes in 10 episodes: bootstrap [1, 1], Wilson [0.72, 1]). A paired difference of two
rates gets Newcombe's hybrid score interval (method 10 of Newcombe 1998, "Improved confidence
intervals for the difference between binomial proportions based on paired data", Stat. Med. 17),
built from the two Wilson intervals and the correlation of the pairs (as Fagerland, Lydersen and Laake,
"Statistical Analysis of Contingency Tables", 2017, ch. 8, give it: "Newcombe square-and-add"). Other
means get the percentile bootstrap (`Bootstrap`).

Below `MIN_INTERVAL_N` values (episodes, or pairs of episodes) no bootstrap interval is given: resampling one
value gives a zero-width "interval" and resampling two to five gives little more than their range, which is no
95 % interval at all. The mean is still reported, with its n; a rate keeps its Wilson interval (and a paired
difference of rates its Newcombe interval), whose coverage holds at small n; but no difference is said to
exclude zero and no MDD is derived from the observed spread below it (`compare.results.summary`).

The minimum detectable difference (MDD) of a paired comparison at n pairs is the true mean difference a
two-sided test at level alpha detects with the given power: (z_{1-alpha/2} + z_{power}) * sd_d / sqrt(n),
sd_d the standard deviation of the paired differences (normal approximation). Before any run, for a
rate, `design_mdd_rate` takes the worst case p = 0.5 for both pilots with independent outcomes
(sd_d = sqrt(2 p (1 - p))); pairing only narrows it when the two pilots' outcomes correlate. After a run, a
paired difference of rates gets `paired_mdd`: Connor's (1987) sample size of McNemar's test solved for the
difference, from the observed share of discordant pairs (the pairs on which only one of the two had the outcome).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uam_fdm.stats import wilson_interval, z_quantile

MIN_INTERVAL_N = 10
"""Fewest values (episodes, or pairs) for a bootstrap interval, an MDD from the observed spread, or a verdict that a
difference excludes zero; below it the summary gives the mean and n only (rates keep their score intervals)."""

DESIGN_RATE = 0.5
"""The rate assumed for the design value of a rate's MDD: the largest variance, p (1 - p) = 1/4."""


class OutcomeRates:
    """Success and collision rates of a group of episodes, for a frozen dataclass with the counts `episodes`,
    `successes` and `collisions` (the sweep's steps, the benchmark's levels)."""

    episodes: int
    successes: int
    collisions: int

    @property
    def success(self) -> float:
        """Success rate (NaN without episodes)."""
        return self.successes / self.episodes if self.episodes else math.nan

    @property
    def collision(self) -> float:
        """Collision rate (NaN without episodes)."""
        return self.collisions / self.episodes if self.episodes else math.nan


@dataclass(frozen=True)
class PairedCounts:
    """Paired 0/1 outcomes of two pilots on the same cells: both 1, first only, second only, neither."""

    both: int
    first_only: int
    second_only: int
    neither: int

    @property
    def n(self) -> int:
        return self.both + self.first_only + self.second_only + self.neither

    @classmethod
    def of(cls, first: np.ndarray, second: np.ndarray) -> PairedCounts:
        """Counts of two equally long 0/1 (or bool) arrays, pair by pair."""
        a, b = np.asarray(first, bool), np.asarray(second, bool)
        return cls(int(np.sum(a & b)), int(np.sum(a & ~b)), int(np.sum(~a & b)), int(np.sum(~a & ~b)))


def newcombe_paired_interval(counts: PairedCounts, confidence: float = 0.95) -> tuple[float, float]:
    """Newcombe's hybrid score interval (his method 10) of the difference of two paired rates, first - second.

    Args:
        counts: the paired outcomes (n >= 1).
        confidence: two-sided level in (0, 1).

    Returns:
        (low, high) of the difference, inside [-1, 1].
    """
    a, b, c, d, n = counts.both, counts.first_only, counts.second_only, counts.neither, counts.n
    if n < 1:
        raise ValueError("a paired difference of rates needs at least one pair")
    p1, p2 = (a + b) / n, (a + c) / n
    l1, u1 = wilson_interval(a + b, n, confidence)
    l2, u2 = wilson_interval(a + c, n, confidence)
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    cross = a * d - b * c
    # the correlation of the pairs, a positive one shrunk by n/2 (Newcombe's continuity correction)
    if margins == 0 or 0 <= cross <= n / 2:
        phi = 0.0
    else:
        phi = (cross - n / 2 if cross > 0 else cross) / math.sqrt(margins)
    delta = math.sqrt(max(0.0, (p1 - l1) ** 2 - 2.0 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    epsilon = math.sqrt(max(0.0, (u1 - p1) ** 2 - 2.0 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    diff = p1 - p2
    return max(-1.0, diff - delta), min(1.0, diff + epsilon)


def mdd(sd: float, n: int, alpha: float = 0.05, power: float = 0.8) -> float:
    """Minimum detectable difference of a paired mean: (z_{1-alpha/2} + z_power) * sd / sqrt(n).

    Args:
        sd: standard deviation of the paired differences (the metric's unit).
        n: pairs (>= 1).
        alpha: two-sided significance level. power: the probability of detecting a true difference of that size.
    """
    if n < 1:
        raise ValueError(f"an MDD needs at least one pair, got {n}")
    return (z_quantile(1.0 - alpha / 2.0) + z_quantile(power)) * sd / math.sqrt(n)


def design_mdd_rate(n: int, alpha: float = 0.05, power: float = 0.8, rate: float = DESIGN_RATE) -> float:
    """The MDD of a paired difference of rates before any run: both pilots at `rate`, outcomes independent
    (sd_d = sqrt(2 rate (1 - rate)); at 0.5 the largest). A fraction, like the rates."""
    return mdd(math.sqrt(2.0 * rate * (1.0 - rate)), n, alpha, power)


def paired_mdd(counts: PairedCounts, alpha: float = 0.05, power: float = 0.8) -> float:
    """The minimum detectable difference of two paired rates from their observed discordance: the smallest true
    difference, first - second in either direction, that a two-sided McNemar test at `alpha` detects with
    probability `power` on `counts.n` pairs. A fraction, like the rates (0.03 is 3 points).

    It solves Connor's (1987, Biometrics 43, "Sample size for testing differences in proportions for the
    paired-sample design") n delta^2 = (z_{1-alpha/2} sqrt(psi) + z_power sqrt(psi - delta^2))^2 for delta in
    (0, 1], with psi = max((first_only + second_only) / n, delta). The floor is there because a difference delta
    needs at least delta of the pairs discordant: a run whose pilots always agreed gives about
    (z_{1-alpha/2} + z_power)^2 / n, the least any n pairs can detect, never 0.

    Args:
        counts: the paired outcomes (n >= 1).
        alpha: two-sided significance level in (0, 1). power: in [0.5, 1).

    Returns:
        The difference as a fraction in (0, 1]; infinity when even a difference of 1 is not detected (n below
        z_{1-alpha/2}^2: 3 pairs or fewer at alpha 0.05).
    """
    n = counts.n
    if n < 1:
        raise ValueError(f"an MDD needs at least one pair, got {n}")
    if not 0.0 < alpha < 1.0 or not 0.5 <= power < 1.0:
        # below power 0.5 z_power is negative and the equation's root need not be unique
        raise ValueError(f"a paired MDD needs alpha in (0, 1) and power in [0.5, 1), got {alpha}, {power}")
    z_a, z_b = z_quantile(1.0 - alpha / 2.0), z_quantile(power)
    observed = (counts.first_only + counts.second_only) / n

    def detected(delta: float) -> bool:
        psi = max(observed, delta)
        return n * delta * delta >= (z_a * math.sqrt(psi) + z_b * math.sqrt(max(0.0, psi - delta * delta))) ** 2

    # n delta^2 minus the right side changes sign once on (0, 1]: with psi fixed it grows with delta, and where
    # psi = delta, divided by delta it is n delta - (z_a + z_b sqrt(1 - delta))^2, which grows too; so bisect
    if not detected(1.0):
        return math.inf
    low, high = 0.0, 1.0
    while high - low > 1e-12:
        mid = 0.5 * (low + high)
        low, high = (low, mid) if detected(mid) else (mid, high)
    return high


@dataclass(frozen=True)
class Bootstrap:
    """The percentile bootstrap of a mean: `resamples` (>= 1), two-sided `confidence` in (0, 1), `seed`, and the
    fewest values `min_n` (>= 2) it gives an interval for.

    Every interval draws from a fresh `numpy.random.default_rng(seed)`, so a mean's interval depends only
    on its own sample.
    """

    resamples: int
    confidence: float
    seed: int
    min_n: int = MIN_INTERVAL_N

    def mean_ci(self, x: np.ndarray) -> tuple[float | None, float | None, float | None]:
        """Mean of `x` and its percentile bootstrap CI: None x 3 for an empty sample, (mean, None, None) for fewer
        than `min_n` values (too few to resample)."""
        n = x.size
        if n == 0:
            return None, None, None
        mean = float(np.mean(x))
        if n < max(self.min_n, 2):
            return mean, None, None
        rng = np.random.default_rng(self.seed)
        idx = rng.integers(0, n, size=(self.resamples, n))   # one row per resample
        means = x[idx].mean(axis=1)
        tail = (1.0 - self.confidence) / 2.0
        lo, hi = np.quantile(means, [tail, 1.0 - tail])
        return mean, float(lo), float(hi)
