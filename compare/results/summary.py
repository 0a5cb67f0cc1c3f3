"""The per-method summary of a run's metrics, `summary.json`, with bootstrap confidence intervals.

`summarize` aggregates `EpisodeMetrics` rows per method (mean and percentile-bootstrap CI) and pairs
methods on the episodes both flew (mean difference and its CI); `summarize_run` adds the same per
scenario. A `Summary` is written by `write_summary_json` and read by `read_summary_json`, nowhere else;
the file's format is unchanged since the first runs (NaN and infinities as null, a paired difference
under "mean_diff", pairs keyed "a - b"). `methods_table` formats a summary as text cells.
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

from compare.results.metrics import (
    CLEARANCE_THRESHOLDS_M,
    TRACKER_METRICS,
    EpisodeMetrics,
    below_field,
    cell_order,
)
from uam_fdm.files.atomic import write_text_atomic

SUMMARY_METRICS = ("success", "collision", "min_clearance_m", "time_below_2m_s", "time_below_5m_s",
                   "time_s", "path_length_m", "spl", "energy_kj", "compute_ms_mean", "compute_ms_max",
                   "plan_time_s") + TRACKER_METRICS
"""Fields aggregated by `summarize`, in report order (the tracker columns are not paired)."""

SUCCESS_ONLY_METRICS = ("time_s", "path_length_m", "energy_kj")
"""Metrics averaged over successful episodes only (a crash after 3 s is not a fast flight)."""


@dataclass(frozen=True)
class Stat:
    """A mean and its confidence interval over `n` values (None × 3 where n is 0).

    Attributes:
        mean: the mean; in a paired summary, the mean of the per-episode differences (`mean_diff` in the file).
        ci_low, ci_high: the bootstrap CI of the mean.
        n: the values used (episodes, or pairs of episodes).
        over: "successes" (successful episodes only, `SUCCESS_ONLY_METRICS`) or "all" (None where not recorded).
    """

    mean: float | None
    ci_low: float | None
    ci_high: float | None
    n: int = 0
    over: str | None = None


@dataclass(frozen=True)
class MethodSummary:
    """One method: its episode count, failures by reason, and a `Stat` per metric (by name, report order)."""

    episodes: int
    failure_reasons: Mapping[str, int] = field(default_factory=dict)
    stats: Mapping[str, Stat] = field(default_factory=dict)


@dataclass(frozen=True)
class PairedSummary:
    """Two methods on the episodes both flew: `first` − `second` per metric (`Stat.mean` is the mean difference)."""

    first: str
    second: str
    episodes: int
    stats: Mapping[str, Stat] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The pair's key in summary.json, "first - second"."""
        return f"{self.first} - {self.second}"


@dataclass(frozen=True)
class BootstrapSettings:
    """How the intervals were drawn: resamples, confidence level in (0, 1), seed, and the CI method."""

    resamples: int | None = None
    confidence: float | None = None
    seed: int | None = None
    method: str | None = None


@dataclass(frozen=True)
class Summary:
    """The contents of `summary.json`.

    Attributes:
        bootstrap: the bootstrap settings.
        metrics: the summarised metrics, in report order.
        methods: per method, by name (sorted).
        paired: per pair of methods (first < second by name).
        by_scenario: the same per scenario (a run may mix vehicles, whose energies do not average), by
            scenario name; None for a summary that is itself one scenario's, or one written without them.
    """

    bootstrap: BootstrapSettings
    metrics: tuple[str, ...]
    methods: Mapping[str, MethodSummary]
    paired: tuple[PairedSummary, ...] = ()
    by_scenario: Mapping[str, Summary] | None = None


# ---- aggregation ------------------------------------------------------------------------------------------
def summarize(rows: Iterable[EpisodeMetrics], *, resamples: int = 2000, confidence: float = 0.95,
              seed: int = 0) -> Summary:
    """Aggregate episode rows per method and per pair of methods, with percentile-bootstrap CIs.

    Per method and metric in `SUMMARY_METRICS`: the mean over episodes (NaNs dropped per metric) and a
    percentile bootstrap CI of the mean (episodes resampled with replacement); `n` is the count used;
    with n == 0 every number is None, with n == 1 the CI is the mean. `time_s`, `path_length_m` and
    `energy_kj` are over successful episodes only (`over` "successes"), the rest over all
    episodes (`over` "all").

    Paired: for each pair of methods a < b (sorted names), the episodes both flew with the same
    (scenario, episode, seed); per metric the mean of the differences a − b and a bootstrap CI of that
    mean (pairs resampled). For the success-only metrics only pairs where both succeeded.

    Each CI draws from a fresh `numpy.random.default_rng(seed)`, so a method's numbers depend only on
    its own episodes, and the same rows (in any order) give the same summary.

    Args:
        rows: episode metrics, one per (scenario, episode, method, seed).
        resamples: bootstrap resamples (≥ 1).
        confidence: CI level in (0, 1).
        seed: bootstrap seed.

    Returns:
        The `Summary` (without `by_scenario`).

    Raises:
        ValueError: bad bootstrap settings or two rows for the same cell.
    """
    if int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples must be a positive integer, got {resamples!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    boot = _Bootstrap(int(resamples), float(confidence), int(seed))
    by_method = _group_by_method(rows)
    methods = sorted(by_method)
    paired = tuple(_paired_summary(a, b, by_method[a], by_method[b], boot)
                   for i, a in enumerate(methods) for b in methods[i + 1:])
    return Summary(
        bootstrap=BootstrapSettings(boot.resamples, boot.confidence, boot.seed, "percentile"),
        metrics=SUMMARY_METRICS,
        methods={m: _method_summary(by_method[m], boot) for m in methods},
        paired=paired,
    )


def summarize_run(rows: Sequence[EpisodeMetrics]) -> Summary:
    """`summarize` over all rows, with `by_scenario` (each scenario's rows summarised alike), as a run saves it."""
    by_scenario = {name: summarize([r for r in rows if r.scenario == name])
                   for name in sorted({r.scenario for r in rows})}
    whole = summarize(rows)
    return Summary(whole.bootstrap, whole.metrics, whole.methods, whole.paired, by_scenario)


@dataclass(frozen=True)
class _Bootstrap:
    resamples: int
    confidence: float
    seed: int

    def mean_ci(self, x: np.ndarray) -> tuple[float | None, float | None, float | None]:
        """Mean of `x` and its percentile bootstrap CI (None × 3 for an empty sample)."""
        n = x.size
        if n == 0:
            return None, None, None
        mean = float(np.mean(x))
        if n == 1:
            return mean, mean, mean
        rng = np.random.default_rng(self.seed)
        idx = rng.integers(0, n, size=(self.resamples, n))   # one row per resample
        means = x[idx].mean(axis=1)
        tail = (1.0 - self.confidence) / 2.0
        lo, hi = np.quantile(means, [tail, 1.0 - tail])
        return mean, float(lo), float(hi)

    def stat(self, x: np.ndarray, metric: str) -> Stat:
        """The `Stat` of the finite values of `x` for `metric`."""
        x = x[~np.isnan(x)]
        return Stat(*self.mean_ci(x), n=int(x.size), over=_over(metric))


def _group_by_method(rows: Iterable[EpisodeMetrics]) -> dict[str, list[EpisodeMetrics]]:
    """Rows per method, each list sorted by cell; rejects duplicate cells."""
    by_method: dict[str, list[EpisodeMetrics]] = {}
    seen: set[tuple[str, int, str, int]] = set()
    for row in sorted(rows, key=cell_order):
        cell = cell_order(row)
        if cell in seen:
            raise ValueError(f"two rows for scenario {row.scenario!r}, episode {row.episode}, "
                             f"method {row.method!r}, seed {row.seed}")
        seen.add(cell)
        by_method.setdefault(row.method, []).append(row)
    return by_method


def _over(metric: str) -> str:
    return "successes" if metric in SUCCESS_ONLY_METRICS else "all"


def _values(rows: Sequence[EpisodeMetrics], metric: str) -> np.ndarray:
    return np.array([float(getattr(r, metric)) for r in rows], dtype=float)


def _method_summary(rows: list[EpisodeMetrics], boot: _Bootstrap) -> MethodSummary:
    reasons = Counter(r.failure_reason for r in rows if r.failure_reason)
    stats = {}
    for metric in SUMMARY_METRICS:
        used = [r for r in rows if r.success] if metric in SUCCESS_ONLY_METRICS else rows
        stats[metric] = boot.stat(_values(used, metric), metric)
    return MethodSummary(len(rows), dict(sorted(reasons.items())), stats)


def _paired_summary(first: str, second: str, rows_a: list[EpisodeMetrics], rows_b: list[EpisodeMetrics],
                    boot: _Bootstrap) -> PairedSummary:
    a = {(r.scenario, r.episode, r.seed): r for r in rows_a}
    b = {(r.scenario, r.episode, r.seed): r for r in rows_b}
    common = sorted(a.keys() & b.keys())
    stats = {}
    for metric in SUMMARY_METRICS:
        if metric in TRACKER_METRICS:
            continue
        cells = [c for c in common
                 if metric not in SUCCESS_ONLY_METRICS or (a[c].success and b[c].success)]
        d = _values([a[c] for c in cells], metric) - _values([b[c] for c in cells], metric)
        stats[metric] = boot.stat(d, metric)
    return PairedSummary(first, second, len(common), stats)


# ---- summary.json -----------------------------------------------------------------------------------------
def write_summary_json(summary: Summary, path: Path) -> Path:
    """Write a summary as `summary.json` atomically (indent 2, NaN and infinities as null).

    Returns:
        The path written.
    """
    text = json.dumps(summary_to_json(summary), indent=2, allow_nan=False) + "\n"
    return write_text_atomic(Path(path), text)


def summary_to_json(summary: Summary) -> dict[str, Any]:
    """`summary` as the plain data of summary.json, keys in the file's order."""
    b = summary.bootstrap
    out: dict[str, Any] = {
        "bootstrap": {"resamples": b.resamples, "confidence": b.confidence, "seed": b.seed, "method": b.method},
        "metrics": list(summary.metrics),
        "methods": {m: {"episodes": s.episodes, "failure_reasons": dict(s.failure_reasons),
                        **{k: _stat_json(v, "mean") for k, v in s.stats.items()}}
                    for m, s in summary.methods.items()},
        "paired": {p.name: {"episodes": p.episodes, **{k: _stat_json(v, "mean_diff") for k, v in p.stats.items()}}
                   for p in summary.paired},
    }
    if summary.by_scenario is not None:
        out["by_scenario"] = {name: summary_to_json(s) for name, s in summary.by_scenario.items()}
    return out


def _stat_json(stat: Stat, mean_key: str) -> dict[str, Any]:
    return {mean_key: _finite(stat.mean), "ci_low": _finite(stat.ci_low), "ci_high": _finite(stat.ci_high),
            "n": stat.n, "over": stat.over}


def _finite(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def read_summary_json(path: Path) -> Summary:
    """Read a `summary.json` written by `write_summary_json` (absent entries read as empty or None).

    Raises:
        ValueError: the file cannot be read, is not JSON, or holds a value of the wrong kind, naming the
            file and the key.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from exc
    return _summary_from_json(data, str(path), "")


def _summary_from_json(data: Any, where: str, prefix: str) -> Summary:
    top = _mapping(data, where, prefix or "<root>")
    boot = _mapping(top.get("bootstrap"), where, f"{prefix}bootstrap")
    methods = _mapping(top.get("methods"), where, f"{prefix}methods")
    paired = _mapping(top.get("paired"), where, f"{prefix}paired")
    by_scenario = top.get("by_scenario")
    return Summary(
        bootstrap=BootstrapSettings(
            _integer(boot.get("resamples"), where, f"{prefix}bootstrap.resamples"),
            _number(boot.get("confidence"), where, f"{prefix}bootstrap.confidence"),
            _integer(boot.get("seed"), where, f"{prefix}bootstrap.seed"),
            None if boot.get("method") is None else str(boot["method"])),
        metrics=tuple(str(m) for m in _list(top.get("metrics"), where, f"{prefix}metrics")),
        methods={str(m): _method_from_json(v, where, f"{prefix}methods.{m}") for m, v in methods.items()},
        paired=tuple(_paired_from_json(str(k), v, where, f"{prefix}paired.{k}") for k, v in paired.items()),
        by_scenario=None if by_scenario is None else {
            str(name): _summary_from_json(s, where, f"{prefix}by_scenario.{name}.")
            for name, s in _mapping(by_scenario, where, f"{prefix}by_scenario").items()},
    )


def _method_from_json(data: Any, where: str, key: str) -> MethodSummary:
    d = _mapping(data, where, key)
    reasons = _mapping(d.get("failure_reasons"), where, f"{key}.failure_reasons")
    return MethodSummary(
        episodes=_integer(d.get("episodes"), where, f"{key}.episodes") or 0,
        failure_reasons={str(r): _integer(n, where, f"{key}.failure_reasons.{r}") or 0 for r, n in reasons.items()},
        stats={str(k): _stat_from_json(v, "mean", where, f"{key}.{k}") for k, v in d.items()
               if k not in ("episodes", "failure_reasons")})


def _paired_from_json(name: str, data: Any, where: str, key: str) -> PairedSummary:
    first, sep, second = name.partition(" - ")
    if not sep:
        raise ValueError(f"{where}: {key}: a pair's key must read \"first - second\"")
    d = _mapping(data, where, key)
    return PairedSummary(first, second, _integer(d.get("episodes"), where, f"{key}.episodes") or 0,
                         {str(k): _stat_from_json(v, "mean_diff", where, f"{key}.{k}") for k, v in d.items()
                          if k != "episodes"})


def _stat_from_json(data: Any, mean_key: str, where: str, key: str) -> Stat:
    d = _mapping(data, where, key)
    return Stat(_number(d.get(mean_key), where, f"{key}.{mean_key}"), _number(d.get("ci_low"), where, f"{key}.ci_low"),
                _number(d.get("ci_high"), where, f"{key}.ci_high"), _integer(d.get("n"), where, f"{key}.n") or 0,
                None if d.get("over") is None else str(d["over"]))


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


# ---- the methods table ------------------------------------------------------------------------------------
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
}


def methods_table(summary: Summary) -> list[list[str]]:
    """The per-method table of a summary as text cells, "mean [ci_low, ci_high]" per metric.

    Args:
        summary: as returned by `summarize` (or read back from `summary.json`).

    Returns:
        A header row, then one row per method: name, episode count, one cell per summarised metric
        ("n/a" where no episode counted, e.g. the planning time of a pilot that does not plan).
    """
    metrics = list(summary.metrics)
    header = ["method", "episodes"] + [_TABLE_COLUMNS.get(m, (m, None))[0] for m in metrics]
    table = [header]
    for method, s in summary.methods.items():
        row = [method, str(s.episodes)]
        for m in metrics:
            fmt = _TABLE_COLUMNS.get(m, (m, lambda v: f"{v:.3g}"))[1]
            row.append(_format_stat(s.stats.get(m), fmt))
        table.append(row)
    return table


def _format_stat(stat: Stat | None, fmt: Callable[[float], str]) -> str:
    if stat is None or stat.mean is None:
        return "n/a"
    if stat.ci_low is None or stat.ci_high is None:
        return fmt(stat.mean)
    return f"{fmt(stat.mean)} [{fmt(stat.ci_low)}, {fmt(stat.ci_high)}]"
