"""The summary of a run's metrics, `summary.json`: per vehicle, per pilot and per pair of pilots, with intervals.

A summary never pools vehicles (a small quadrotor's and a passenger multicopter's energies, times and
even success rates are different quantities). `summarize` takes the rows of one vehicle: per pilot
each metric's mean with a 95 % interval (Wilson for the rates `RATE_METRICS`, the percentile bootstrap
for the rest), and per pair of pilots the paired differences on the episodes both flew, with their
interval (Newcombe's for rates, the bootstrap for the rest) and the minimum detectable difference (MDD)
at that many pairs (`compare.results.stats`). `summarize_run` summarises each vehicle and each scenario
alike; its run-wide block holds statistics only when the run flew one vehicle.

Small samples are reported as such: below `MIN_INTERVAL_N` values a mean has no bootstrap interval (null in the
file, "n=3, no CI" in a table: `format_stat`), a paired difference neither an MDD from its spread nor a verdict
that it excludes zero (`PairedStat.excludes_zero`, `mdd_gap`); a rate keeps its Wilson interval at any n.

A `Summary` is written by `write_summary_json` and read by `read_summary_json`, nowhere else. Files
written before the per-vehicle summaries still read: their keys are unchanged (NaN and infinities as
null, a paired difference under "mean_diff", pairs keyed "a - b"); what they lack reads as empty (no
vehicles, no per-vehicle part, intervals and power not recorded). A nested summary (per vehicle, per
scenario) leaves out the settings it shares with the summary it sits in. `pilots_table` formats a
summary as text cells.
"""
from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from compare.flying import pilots
from compare.results.metrics import (
    CLEARANCE_THRESHOLDS_M,
    MAPPING_METRICS,
    TRACKER_METRICS,
    EpisodeMetrics,
    below_field,
    cell_order,
    label_vehicles,
)
from compare.results.stats import (
    DESIGN_RATE,
    MIN_INTERVAL_N,
    Bootstrap,
    PairedCounts,
    design_mdd_rate,
    mdd,
    newcombe_paired_interval,
)
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.strict import strict_json_loads
from uam_fdm.stats import wilson_interval

SUMMARY_METRICS = ("success", "collision", "min_clearance_m", "time_below_2m_s", "time_below_5m_s",
                   "time_s", "path_length_m", "spl", "energy_kj", "compute_ms_mean", "compute_ms_max",
                   "plan_time_s") + TRACKER_METRICS + MAPPING_METRICS
"""Fields aggregated by `summarize`, in report order (the tracker and mapping columns are not paired)."""

SUCCESS_ONLY_METRICS = ("time_s", "path_length_m", "energy_kj")
"""Metrics averaged over successful episodes only (a crash after 3 s is not a fast flight)."""

RATE_METRICS = ("success", "collision")
"""The 0/1 metrics: their means are rates, with Wilson intervals (paired: Newcombe's)."""

WILSON = "wilson"
NEWCOMBE = "newcombe-hybrid-score"


@dataclass(frozen=True)
class Stat:
    """A mean and its confidence interval over `n` values (None × 3 where n is 0).

    Attributes:
        mean: the mean; in a paired summary, the mean of the per-episode differences (`mean_diff` in the file).
        ci_low, ci_high: the CI of the mean (Wilson for a rate, else the bootstrap's; `Summary.intervals`); None
            where there is none (no values, or fewer than `MIN_INTERVAL_N` for the bootstrap).
        n: the values used (episodes, or pairs of episodes).
        over: "successes" (successful episodes only, `SUCCESS_ONLY_METRICS`) or "all" (None where not recorded).
    """

    mean: float | None
    ci_low: float | None
    ci_high: float | None
    n: int = 0
    over: str | None = None


@dataclass(frozen=True)
class PairedStat(Stat):
    """A paired difference (first − second) with what it can detect.

    Attributes:
        sd: standard deviation of the n paired differences (ddof 1; None for n < 2).
        mdd: the minimum detectable difference at n pairs from `sd` (`Summary.power`), in the metric's unit (a
            fraction for rates); None below `MIN_INTERVAL_N` pairs or where every pair agreed (sd 0: the spread
            says nothing), `mdd_gap` says which.
        mdd_design: for a rate, the MDD at n pairs before any run (both at p = 0.5, independent); else None.
    """

    sd: float | None = None
    mdd: float | None = None
    mdd_design: float | None = None

    @property
    def excludes_zero(self) -> bool | None:
        """The interval lies wholly above or below zero (None: no interval, or fewer than `MIN_INTERVAL_N` pairs,
        too few to call a difference)."""
        if self.n < MIN_INTERVAL_N or self.ci_low is None or self.ci_high is None:
            return None
        return self.ci_low > 0.0 or self.ci_high < 0.0


@dataclass(frozen=True)
class PilotSummary:
    """One pilot: its episode count, failures by reason, and a `Stat` per metric (by name, report order)."""

    episodes: int
    failure_reasons: Mapping[str, int] = field(default_factory=dict)
    stats: Mapping[str, Stat] = field(default_factory=dict)


@dataclass(frozen=True)
class PairedSummary:
    """Two pilots on the episodes both flew: `first` − `second` per metric (`Stat.mean` is the mean difference)."""

    first: str
    second: str
    episodes: int
    stats: Mapping[str, PairedStat] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The pair's key in summary.json, "first - second"."""
        return f"{self.first} - {self.second}"


@dataclass(frozen=True)
class BootstrapConfig:
    """How the intervals were drawn: resamples, confidence level in (0, 1), seed, the CI method, and the fewest
    values given an interval (`min_n`; None: not recorded, an older file)."""

    resamples: int | None = None
    confidence: float | None = None
    seed: int | None = None
    method: str | None = None
    min_n: int | None = None


@dataclass(frozen=True)
class IntervalMethods:
    """Which interval the rates carry (None: not recorded, an older file whose intervals are all the bootstrap's).

    Attributes:
        rates: a rate's interval ("wilson"); paired_rates: a paired difference of rates' ("newcombe-hybrid-score").
        rate_metrics: the metrics that are rates.
    """

    rates: str | None = None
    paired_rates: str | None = None
    rate_metrics: tuple[str, ...] = ()


@dataclass(frozen=True)
class PowerConfig:
    """How the minimum detectable differences were computed (None: not recorded, an older file).

    Attributes:
        alpha: two-sided significance level. power: probability of detecting a true difference of the MDD.
        design_rate: the rate both pilots are assumed to have in a rate's design value (0.5, the worst case).
    """

    alpha: float | None = None
    power: float | None = None
    design_rate: float | None = None


@dataclass(frozen=True)
class Summary:
    """The contents of `summary.json`, or one part of it (a vehicle's, a scenario's).

    Attributes:
        bootstrap: the bootstrap settings.
        metrics: the summarised metrics, in report order.
        pilots: per pilot, in table order (`compare.flying.pilots.ordered`); empty in a run-wide summary of
            several vehicles (the key "methods" in summary.json).
        paired: per pair of pilots (first < second by name); empty where `pilots` is.
        by_scenario: the same per scenario, by scenario name; None for a summary that is itself one
            scenario's or one vehicle's, or one written without them.
        vehicles: the vehicles whose rows were summarised, sorted (empty in files written before they were
            recorded: such a run-wide block may pool vehicles).
        by_vehicle: the same per vehicle, by vehicle name (None: not a run's summary, or an older file).
        intervals: which interval the rates carry. power: how the MDDs were computed.
    """

    bootstrap: BootstrapConfig
    metrics: tuple[str, ...]
    pilots: Mapping[str, PilotSummary]
    paired: tuple[PairedSummary, ...] = ()
    by_scenario: Mapping[str, Summary] | None = None
    vehicles: tuple[str, ...] = ()
    by_vehicle: Mapping[str, Summary] | None = None
    intervals: IntervalMethods = IntervalMethods()
    power: PowerConfig = PowerConfig()

    @property
    def vehicle(self) -> str | None:
        """The one vehicle summarised, or None (several, or not recorded)."""
        return self.vehicles[0] if len(self.vehicles) == 1 else None

    def per_vehicle(self) -> Mapping[str, Summary] | None:
        """The summary of each vehicle: `by_vehicle`, or this summary itself when it is one vehicle's; None
        when the file cannot say (an older file: recompute from metrics.csv with `summarize_run`)."""
        if self.by_vehicle is not None:
            return self.by_vehicle
        return {self.vehicles[0]: self} if len(self.vehicles) == 1 else None


# ---- aggregation ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _StatsConfig:
    boot: Bootstrap
    alpha: float
    power: float

    @property
    def confidence(self) -> float:
        return self.boot.confidence

    def stat(self, x: np.ndarray, metric: str) -> Stat:
        """The `Stat` of the finite values of `x` for `metric` (Wilson for a rate)."""
        x = x[~np.isnan(x)]
        if metric in RATE_METRICS and x.size:
            low, high = wilson_interval(int(np.sum(x)), int(x.size), self.confidence)
            return Stat(float(np.mean(x)), low, high, int(x.size), _over(metric))
        return Stat(*self.boot.mean_ci(x), n=int(x.size), over=_over(metric))

    def paired_stat(self, a: np.ndarray, b: np.ndarray, metric: str) -> PairedStat:
        """The `PairedStat` of a − b over the pairs where both are finite."""
        keep = ~(np.isnan(a) | np.isnan(b))
        a, b = a[keep], b[keep]
        d = a - b
        n = int(d.size)
        if metric in RATE_METRICS and n:
            low, high = newcombe_paired_interval(PairedCounts.of(a, b), self.confidence)
            mean: float | None = float(np.mean(d))
            ci: tuple[float | None, float | None] = (low, high)
        else:
            mean, *bounds = self.boot.mean_ci(d)
            ci = (bounds[0], bounds[1])
        sd = float(np.std(d, ddof=1)) if n >= 2 else None
        spread = sd is not None and sd > 0.0 and n >= self.boot.min_n  # else the observed spread says nothing
        return PairedStat(mean, ci[0], ci[1], n, _over(metric), sd=sd,
                          mdd=mdd(sd, n, self.alpha, self.power) if spread and sd is not None else None,
                          mdd_design=design_mdd_rate(n, self.alpha, self.power) if metric in RATE_METRICS and n
                          else None)

    def describe(self) -> tuple[BootstrapConfig, IntervalMethods, PowerConfig]:
        b = self.boot
        return (BootstrapConfig(b.resamples, b.confidence, b.seed, "percentile", b.min_n),
                IntervalMethods(WILSON, NEWCOMBE, RATE_METRICS), PowerConfig(self.alpha, self.power, DESIGN_RATE))


def _stats_config(resamples: int, confidence: float, seed: int, alpha: float, power: float) -> _StatsConfig:
    if int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples must be a positive integer, got {resamples!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    if not 0.0 < power < 1.0:
        raise ValueError(f"power must be in (0, 1), got {power!r}")
    return _StatsConfig(Bootstrap(int(resamples), float(confidence), int(seed)), float(alpha), float(power))


def summarize(rows: Iterable[EpisodeMetrics], *, resamples: int = 2000, confidence: float = 0.95,
              seed: int = 0, alpha: float = 0.05, power: float = 0.8) -> Summary:
    """Aggregate one vehicle's episode rows per pilot and per pair of pilots, with intervals and MDDs.

    Per pilot and metric in `SUMMARY_METRICS`: the mean over episodes (NaNs dropped per metric) and its
    CI: Wilson's for the rates (`RATE_METRICS`), else a percentile bootstrap (episodes resampled with
    replacement; none below `MIN_INTERVAL_N` episodes); `n` is the count used, with n == 0 every number is None.
    `time_s`, `path_length_m` and `energy_kj` are over successful episodes only (`over` "successes"), the
    rest over all episodes (`over` "all").

    Paired: for each pair of pilots a before b in table order (`compare.flying.pilots.ordered`), the episodes both
    flew with the same (scenario, episode, seed); per metric (not the tracker's) the mean of the differences
    a − b and its CI (Newcombe's for rates, else the bootstrap's, pairs resampled; none below `MIN_INTERVAL_N`
    pairs), the standard deviation of the differences, the MDD at that many pairs (two-sided `alpha`, `power`;
    none below `MIN_INTERVAL_N` pairs or where every pair agreed) and, for rates, the design MDD.
    For the success-only metrics only pairs where both succeeded.

    Each bootstrap draws from a fresh `numpy.random.default_rng(seed)`, so a pilot's numbers depend only
    on its own episodes, and the same rows (in any order) give the same summary.

    Args:
        rows: episode metrics of one vehicle, one per (scenario, episode, pilot, seed).
        resamples: bootstrap resamples (≥ 1).
        confidence: CI level in (0, 1).
        seed: bootstrap seed.
        alpha, power: the MDD's two-sided significance level and power, in (0, 1).

    Returns:
        The `Summary` (without `by_scenario` and `by_vehicle`).

    Raises:
        ValueError: bad settings, rows of several vehicles (they never pool: `summarize_run` summarises each),
            or two rows for the same cell.
    """
    settings = _stats_config(resamples, confidence, seed, alpha, power)
    rows = list(rows)
    vehicles = tuple(sorted({r.vehicle for r in label_vehicles(rows)}))
    if len(vehicles) > 1:
        raise ValueError(f"rows of {len(vehicles)} vehicles ({', '.join(vehicles)}): a summary never pools "
                         f"vehicles; summarize each vehicle's rows (summarize_run does)")
    by_pilot = _group_by_pilot(rows)
    flown = pilots.ordered(by_pilot)  # table order: ours first, then plug-ins by name
    paired = tuple(_paired_summary(a, b, by_pilot[a], by_pilot[b], settings)
                   for i, a in enumerate(flown) for b in flown[i + 1:])
    boot, intervals, pw = settings.describe()
    return Summary(
        bootstrap=boot, metrics=SUMMARY_METRICS,
        pilots={m: _pilot_summary(by_pilot[m], settings) for m in flown},
        paired=paired, vehicles=vehicles, intervals=intervals, power=pw,
    )


def summarize_run(rows: Sequence[EpisodeMetrics], *, resamples: int = 2000, confidence: float = 0.95,
                  seed: int = 0, alpha: float = 0.05, power: float = 0.8) -> Summary:
    """A run's summary, as it is saved: `summarize` per vehicle (`by_vehicle`) and per scenario (`by_scenario`).

    The run-wide `pilots` and `paired` are the one vehicle's when the run flew one, else empty: nothing
    is pooled across vehicles. Settings as for `summarize`.

    Raises:
        ValueError: as `summarize` (a scenario whose rows name several vehicles included).
    """
    kw: dict[str, Any] = {"resamples": resamples, "confidence": confidence, "seed": seed, "alpha": alpha,
                          "power": power}
    rows = label_vehicles(rows)  # two vehicles that share a name are two vehicles
    vehicles = tuple(sorted({r.vehicle for r in rows}))
    by_vehicle = {v: summarize([r for r in rows if r.vehicle == v], **kw) for v in vehicles}
    by_scenario = {name: summarize([r for r in rows if r.scenario == name], **kw)
                   for name in sorted({r.scenario for r in rows})}
    boot, intervals, pw = _stats_config(resamples, confidence, seed, alpha, power).describe()
    one = by_vehicle[vehicles[0]] if len(vehicles) == 1 else None
    return Summary(boot, SUMMARY_METRICS, one.pilots if one else {}, one.paired if one else (), by_scenario,
                   vehicles=vehicles, by_vehicle=by_vehicle, intervals=intervals, power=pw)


def _group_by_pilot(rows: Iterable[EpisodeMetrics]) -> dict[str, list[EpisodeMetrics]]:
    """Rows per pilot, each list sorted by cell; rejects duplicate cells."""
    by_pilot: dict[str, list[EpisodeMetrics]] = {}
    seen: set[tuple[str, int, str, int]] = set()
    for row in sorted(rows, key=cell_order):
        cell = cell_order(row)
        if cell in seen:
            raise ValueError(f"two rows for scenario {row.scenario!r}, episode {row.episode}, "
                             f"pilot {row.method!r}, seed {row.seed}")
        seen.add(cell)
        by_pilot.setdefault(row.method, []).append(row)
    return by_pilot


def _over(metric: str) -> str:
    return "successes" if metric in SUCCESS_ONLY_METRICS else "all"


def _values(rows: Sequence[EpisodeMetrics], metric: str) -> np.ndarray:
    return np.array([float(getattr(r, metric)) for r in rows], dtype=float)


def _pilot_summary(rows: list[EpisodeMetrics], settings: _StatsConfig) -> PilotSummary:
    reasons = Counter(r.failure_reason for r in rows if r.failure_reason)
    stats = {}
    for metric in SUMMARY_METRICS:
        used = [r for r in rows if r.success] if metric in SUCCESS_ONLY_METRICS else rows
        stats[metric] = settings.stat(_values(used, metric), metric)
    return PilotSummary(len(rows), dict(sorted(reasons.items())), stats)


def _paired_summary(first: str, second: str, rows_a: list[EpisodeMetrics], rows_b: list[EpisodeMetrics],
                    settings: _StatsConfig) -> PairedSummary:
    a = {(r.scenario, r.episode, r.seed): r for r in rows_a}
    b = {(r.scenario, r.episode, r.seed): r for r in rows_b}
    common = sorted(a.keys() & b.keys())
    stats = {}
    for metric in SUMMARY_METRICS:
        if metric in TRACKER_METRICS or metric in MAPPING_METRICS:
            continue
        cells = [c for c in common
                 if metric not in SUCCESS_ONLY_METRICS or (a[c].success and b[c].success)]
        stats[metric] = settings.paired_stat(_values([a[c] for c in cells], metric),
                                             _values([b[c] for c in cells], metric), metric)
    return PairedSummary(first, second, len(common), stats)


# ---- summary.json -----------------------------------------------------------------------------------------
def write_summary_json(summary: Summary, path: Path) -> Path:
    """Write a summary as `summary.json` atomically (indent 2, NaN and infinities as null).

    Returns:
        The path written.
    """
    text = json.dumps(summary_to_json(summary), indent=2, allow_nan=False) + "\n"
    return write_text_atomic(Path(path), text)


def summary_to_json(summary: Summary, within: Summary | None = None) -> dict[str, Any]:
    """`summary` as the plain data of summary.json, keys in the file's order.

    Args:
        summary: the summary.
        within: the summary this one is nested in (its settings are left out where they are the same).
    """
    s = summary
    out: dict[str, Any] = {}
    if within is None or s.bootstrap != within.bootstrap:
        b = s.bootstrap
        out["bootstrap"] = {"resamples": b.resamples, "confidence": b.confidence, "seed": b.seed, "method": b.method,
                            "min_n": b.min_n}
    if within is None or s.intervals != within.intervals:
        i = s.intervals
        out["intervals"] = {"rates": i.rates, "paired_rates": i.paired_rates, "rate_metrics": list(i.rate_metrics)}
    if within is None or s.power != within.power:
        p = s.power
        out["power"] = {"alpha": p.alpha, "power": p.power, "design_rate": p.design_rate}
    if within is None or s.metrics != within.metrics:
        out["metrics"] = list(s.metrics)
    out["vehicles"] = list(s.vehicles)
    if s.pilots or s.paired or len(s.vehicles) <= 1:  # a run-wide block of several vehicles holds none
        out["methods"] = {m: {"episodes": ms.episodes, "failure_reasons": dict(ms.failure_reasons),
                              **{k: _stat_json(v) for k, v in ms.stats.items()}}
                          for m, ms in s.pilots.items()}
        out["paired"] = {p.name: {"episodes": p.episodes, **{k: _paired_json(v) for k, v in p.stats.items()}}
                         for p in s.paired}
    if s.by_vehicle is not None:
        out["by_vehicle"] = {name: summary_to_json(part, s) for name, part in s.by_vehicle.items()}
    if s.by_scenario is not None:
        out["by_scenario"] = {name: summary_to_json(part, s) for name, part in s.by_scenario.items()}
    return out


def _stat_json(stat: Stat) -> dict[str, Any]:
    return {"mean": _finite(stat.mean), "ci_low": _finite(stat.ci_low), "ci_high": _finite(stat.ci_high),
            "n": stat.n, "over": stat.over}


def _paired_json(stat: PairedStat) -> dict[str, Any]:
    out = {"mean_diff": _finite(stat.mean), "ci_low": _finite(stat.ci_low), "ci_high": _finite(stat.ci_high),
           "n": stat.n, "over": stat.over, "sd": _finite(stat.sd), "mdd": _finite(stat.mdd)}
    if stat.mdd_design is not None:
        out["mdd_design"] = _finite(stat.mdd_design)
    return out


def _finite(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def read_summary_json(path: Path) -> Summary:
    """Read a `summary.json` written by `write_summary_json`, or by an older version (see the module docstring).

    Raises:
        ValueError: the file cannot be read, is not JSON, or holds a value of the wrong kind, naming the
            file and the key.
    """
    path = Path(path)
    try:
        data = strict_json_loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from exc
    return _summary_from_json(data, str(path), "", None)


def _summary_from_json(data: Any, where: str, prefix: str, within: Summary | None) -> Summary:
    """A summary from its plain data; `within`: the summary it is nested in (settings it leaves out are those)."""
    top = _mapping(data, where, prefix or "<root>")
    flown = _mapping(top.get("methods"), where, f"{prefix}methods")
    paired = _mapping(top.get("paired"), where, f"{prefix}paired")
    own = Summary(
        bootstrap=within.bootstrap if within is not None and "bootstrap" not in top else _bootstrap_from_json(
            top.get("bootstrap"), where, f"{prefix}bootstrap"),
        metrics=within.metrics if within is not None and "metrics" not in top else tuple(
            str(m) for m in _list(top.get("metrics"), where, f"{prefix}metrics")),
        pilots={str(m): _pilot_from_json(v, where, f"{prefix}methods.{m}") for m, v in flown.items()},
        paired=tuple(_paired_from_json(str(k), v, where, f"{prefix}paired.{k}") for k, v in paired.items()),
        vehicles=tuple(str(v) for v in _list(top.get("vehicles"), where, f"{prefix}vehicles")),
        intervals=within.intervals if within is not None and "intervals" not in top else _intervals_from_json(
            top.get("intervals"), where, f"{prefix}intervals"),
        power=within.power if within is not None and "power" not in top else _power_from_json(
            top.get("power"), where, f"{prefix}power"),
    )
    parts = {}
    for key in ("by_vehicle", "by_scenario"):
        value = top.get(key)
        parts[key] = None if value is None else {
            str(name): _summary_from_json(part, where, f"{prefix}{key}.{name}.", own)
            for name, part in _mapping(value, where, f"{prefix}{key}").items()}
    return Summary(own.bootstrap, own.metrics, own.pilots, own.paired, parts["by_scenario"], own.vehicles,
                   parts["by_vehicle"], own.intervals, own.power)


def _bootstrap_from_json(data: Any, where: str, key: str) -> BootstrapConfig:
    boot = _mapping(data, where, key)
    return BootstrapConfig(_integer(boot.get("resamples"), where, f"{key}.resamples"),
                           _number(boot.get("confidence"), where, f"{key}.confidence"),
                           _integer(boot.get("seed"), where, f"{key}.seed"),
                           None if boot.get("method") is None else str(boot["method"]),
                           _integer(boot.get("min_n"), where, f"{key}.min_n"))


def _intervals_from_json(data: Any, where: str, key: str) -> IntervalMethods:
    d = _mapping(data, where, key)
    return IntervalMethods(_text(d.get("rates")), _text(d.get("paired_rates")),
                           tuple(str(m) for m in _list(d.get("rate_metrics"), where, f"{key}.rate_metrics")))


def _power_from_json(data: Any, where: str, key: str) -> PowerConfig:
    d = _mapping(data, where, key)
    return PowerConfig(*(_number(d.get(k), where, f"{key}.{k}") for k in ("alpha", "power", "design_rate")))


def _pilot_from_json(data: Any, where: str, key: str) -> PilotSummary:
    d = _mapping(data, where, key)
    reasons = _mapping(d.get("failure_reasons"), where, f"{key}.failure_reasons")
    return PilotSummary(
        episodes=_integer(d.get("episodes"), where, f"{key}.episodes") or 0,
        failure_reasons={str(r): _integer(n, where, f"{key}.failure_reasons.{r}") or 0 for r, n in reasons.items()},
        stats={str(k): _stat_from_json(v, where, f"{key}.{k}") for k, v in d.items()
               if k not in ("episodes", "failure_reasons")})


def _paired_from_json(name: str, data: Any, where: str, key: str) -> PairedSummary:
    first, sep, second = name.partition(" - ")
    if not sep:
        raise ValueError(f"{where}: {key}: a pair's key must read \"first - second\"")
    d = _mapping(data, where, key)
    return PairedSummary(first, second, _integer(d.get("episodes"), where, f"{key}.episodes") or 0,
                         {str(k): _paired_stat_from_json(v, where, f"{key}.{k}") for k, v in d.items()
                          if k != "episodes"})


def _stat_from_json(data: Any, where: str, key: str) -> Stat:
    d = _mapping(data, where, key)
    return Stat(_number(d.get("mean"), where, f"{key}.mean"), _number(d.get("ci_low"), where, f"{key}.ci_low"),
                _number(d.get("ci_high"), where, f"{key}.ci_high"), _integer(d.get("n"), where, f"{key}.n") or 0,
                _text(d.get("over")))


def _paired_stat_from_json(data: Any, where: str, key: str) -> PairedStat:
    d = _mapping(data, where, key)
    num = {k: _number(d.get(k), where, f"{key}.{k}") for k in ("mean_diff", "ci_low", "ci_high", "sd", "mdd",
                                                                "mdd_design")}
    return PairedStat(num["mean_diff"], num["ci_low"], num["ci_high"], _integer(d.get("n"), where, f"{key}.n") or 0,
                      _text(d.get("over")), sd=num["sd"], mdd=num["mdd"], mdd_design=num["mdd_design"])


def _text(value: Any) -> str | None:
    return None if value is None else str(value)


def _mapping(value: Any, where: str, key: str) -> Mapping[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{where}: {key}: expected a JSON object, got {value!r}")  # noqa: TRY004 (a bad file)
    return value


def _list(value: Any, where: str, key: str) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise ValueError(f"{where}: {key}: expected a JSON list, got {value!r}")  # noqa: TRY004 (a bad file)
    return value


def _number(value: Any, where: str, key: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: {key}: expected a number or null, got {value!r}")  # noqa: TRY004
    return float(value)


def _integer(value: Any, where: str, key: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}: {key}: expected an integer, got {value!r}")  # noqa: TRY004
    return value


# ---- the pilots table -------------------------------------------------------------------------------------
def _percent(v: float) -> str:
    return f"{100.0 * v:.0f}%"


def _fixed(decimals: int) -> Callable[[float], str]:
    return lambda v: f"{v:.{decimals}f}"


# metric → (column header, number format)
_TABLE_COLUMNS: dict[str, tuple[str, Callable[[float], str]]] = {
    "success": ("success", _percent),
    "collision": ("collision", _percent),
    "min_clearance_m": ("min clearance [m]", _fixed(2)),
    **{below_field(th): (f"time < {th:g} m clear [s]", _fixed(2)) for th in CLEARANCE_THRESHOLDS_M},
    "time_s": ("time [s] (successes)", _fixed(1)),
    "path_length_m": ("path [m] (successes)", _fixed(1)),
    "spl": ("SPL", _fixed(2)),
    "energy_kj": ("energy [kJ] (successes)", _fixed(1)),
    "compute_ms_mean": ("compute mean [ms]", _fixed(2)),
    "compute_ms_max": ("compute max [ms]", _fixed(2)),
    "plan_time_s": ("plan time [s]", _fixed(2)),
    "mpc_solve_ms_median": ("MPC solve median [ms]", _fixed(2)),
    "mpc_solve_ms_p95": ("MPC solve p95 [ms]", _fixed(2)),
    "mpc_failures": ("MPC failures", _fixed(1)),
    "replans_tracking": ("replans (tracking error)", _fixed(2)),
    "replans_clearance": ("replans (predicted clearance)", _fixed(2)),
    "tracking_rms_m": ("tracking RMS [m]", _fixed(3)),
    "tracking_max_m": ("tracking max [m]", _fixed(3)),
    "planner_margin_m": ("planner margin [m]", _fixed(2)),
    "mpc_margin_m": ("MPC margin [m]", _fixed(2)),
    "planner_margin_floor_m": ("planner margin at rest [m]", _fixed(2)),
    "planner_attempts": ("planning attempts", _fixed(2)),
    "planner_wall_caps": ("plans cut by the wall-time cap", _fixed(2)),
    "clearance_over_margin_min": ("min clearance / local margin", _fixed(2)),
}


def pilots_table(summary: Summary) -> list[list[str]]:
    """The per-pilot table of a summary as text cells, "mean [ci_low, ci_high]" per metric.

    Args:
        summary: as returned by `summarize` (or read back from `summary.json`).

    Returns:
        A header row, then one row per pilot: name, episode count, one cell per summarised metric
        ("n/a" where no episode counted, e.g. the planning time of a pilot that does not plan).
    """
    metrics = list(summary.metrics)
    header = ["pilot", "episodes"] + [_TABLE_COLUMNS.get(m, (m, None))[0] for m in metrics]
    table = [header]
    for name, s in summary.pilots.items():
        row = [name, str(s.episodes)]
        for m in metrics:
            fmt = _TABLE_COLUMNS.get(m, (m, lambda v: f"{v:.3g}"))[1]
            row.append(format_stat(s.stats.get(m), fmt))
        table.append(row)
    return table


NO_INTERVAL_NOTE = (f"no CI: fewer than {MIN_INTERVAL_N} episodes (or pairs), too few for a bootstrap interval; "
                    f"rates keep their Wilson interval")
"""What "no CI" in a table cell means (`format_stat`), for a line under the table."""


def format_stat(stat: Stat | None, fmt: Callable[[float], str]) -> str:
    """A `Stat` as a cell: "mean [low, high]"; "mean (n=3, no CI)" below `MIN_INTERVAL_N` values without an
    interval (`NO_INTERVAL_NOTE`); the mean alone where a file recorded no interval; "n/a" without a mean.

    Args:
        stat: the statistic (None: not summarised).
        fmt: formats one number (scaled and rounded as the table wants).
    """
    if stat is None or stat.mean is None or not math.isfinite(stat.mean):
        return "n/a"
    if stat.ci_low is None or stat.ci_high is None or not (math.isfinite(stat.ci_low)
                                                            and math.isfinite(stat.ci_high)):
        return fmt(stat.mean) + (f" (n={stat.n}, no CI)" if 0 < stat.n < MIN_INTERVAL_N else "")
    return f"{fmt(stat.mean)} [{fmt(stat.ci_low)}, {fmt(stat.ci_high)}]"


def mdd_gap(stat: PairedStat) -> str:
    """Why a paired difference has no MDD from its observed spread ("" when it has one, or none was recorded for
    another reason): every pair agreed (sd 0), or fewer than `MIN_INTERVAL_N` pairs. Checked in that order,
    so a file written before small samples were flagged (its MDD 0 where every pair agreed) reads alike."""
    if stat.n == 0:
        return "no pairs"
    if stat.sd == 0.0:
        return "every pair agreed"
    if stat.n < MIN_INTERVAL_N:
        return f"fewer than {MIN_INTERVAL_N} pairs"
    return ""
