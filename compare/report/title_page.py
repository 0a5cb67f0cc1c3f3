"""The report's first pages: the run's headline, then what was flown and with what.

Page 1 ("uam-compare report") answers the run's question before anything else: per vehicle (never pooled) and
pilot the episodes, success and collision rates with their Wilson 95 % intervals, and per pair of pilots the
paired differences of those rates (Newcombe intervals; never called below `MIN_INTERVAL_N` pairs), the numbers
`uam-compare run` prints and summary.json holds. "About this run" follows: the scenarios, the pilots and their
policies, notes, fairness, software versions.

No page shows a path of the machine that made the run: a recorded path is shown relative to the run folder when it
lies inside it, as a path in uam-compare's own tree when it is one of its shipped files, as the user wrote it on
the command line when they did, else relative to the run folder (`shown_path`).
"""
from __future__ import annotations

import math
import os
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

from compare.report.layout import Block, Gap, Heading, Paragraph, TableBlock, as_blocks, flow_pages
from compare.report.metrics_pages import PilotStyle, format_ci
from compare.results.run_info import RunInfo, ScenarioInfo
from compare.results.stats import MIN_INTERVAL_N
from compare.results.summary import PairedStat, Summary
from uam_fdm.air.shear import ShearLaw, WindShear

PACKAGE_ROOT = Path(__file__).resolve().parents[2]
"""The folder holding uam-compare's packages (a shipped file's path is shown from here)."""
PACKAGES = ("compare", "rl", "uam_fdm", "planners")


def shown_path(recorded: str, run_dir: Path, command: str = "") -> str:
    """A path run.json recorded, as a report shows it: never the machine's absolute path unless the user typed it.

    Args:
        recorded: the path as recorded (absolute, usually).
        run_dir: the run folder.
        command: the command line that made the run (run.json's), whose arguments are the user's own spelling.

    Returns:
        Relative to the run folder when inside it; "compare/scenarios/default/x.yaml (shipped)" for a file of
        uam-compare's own tree; the command-line argument naming it (the longest that ends like it); else relative
        to the run folder.
    """
    if not recorded:
        return recorded
    path = Path(recorded)
    if not path.is_absolute():
        return recorded
    base = Path(os.path.abspath(run_dir))
    for root in (base, base.resolve()):
        if path == root or root in path.parents:
            return path.relative_to(root).as_posix() or "."
    parts = path.parts
    for k in range(1, len(parts)):
        if parts[k] in PACKAGES and PACKAGE_ROOT.joinpath(*parts[k:]).exists():
            return "/".join(parts[k:]) + " (shipped)"
    try:
        tokens = shlex.split(command)
    except ValueError:  # an unbalanced quote in a hand-edited run.json
        tokens = command.split()
    named = [t for t in tokens[1:] if t and not t.startswith("-") and ".." not in Path(t).parts
             and _ends_like(parts, Path(t).parts)]
    if named:
        return max(named, key=lambda t: len(Path(t).parts))
    try:
        return Path(os.path.relpath(path, base)).as_posix()
    except ValueError:  # another drive (Windows)
        return path.name


def _ends_like(parts: tuple[str, ...], tail: tuple[str, ...]) -> bool:
    tail = tuple(p for p in tail if p not in (".", ""))
    return bool(tail) and len(tail) <= len(parts) and parts[-len(tail):] == tail


@dataclass(frozen=True)
class TitleFacts:
    """What the first pages say of a run.

    Attributes:
        run_dir: the run folder. info: its run.json.
        label: a pilot's display label.
        present, planned: episodes in the report and planned.
        vehicles: each vehicle's summary, in run order (None: no metrics to summarise; `why` says why).
        style: the pilots' order, labels and colours.
        source: where the numbers come from (a sentence).
    """

    run_dir: Path
    info: RunInfo
    label: Callable[[str], str]
    present: int
    planned: int
    vehicles: Mapping[str, Summary] | None
    style: PilotStyle
    source: str = ""
    why: str = ""


def headline_pages(facts: TitleFacts, summary_report: bool = False) -> list[Figure]:
    """Page 1: the run in one sentence, and per vehicle the pilots' rates and their paired differences."""
    info = facts.info
    blocks: list[Block] = [Paragraph(f"Run {facts.run_dir.name}, created {info.created_utc or 'n/a'} by: "
                                     f"{info.command or 'n/a'}")]
    if info.task_set is not None:  # a benchmark set: its version names the exact tasks flown
        ts = info.task_set
        blocks.append(Paragraph(f"Task set {ts.name}, version {ts.version}: {ts.description}"))
    coverage = f"Episodes in this report: {facts.present} of {facts.planned} planned."
    if facts.present < facts.planned:
        coverage += " The run is incomplete (interrupted): the report covers the episodes saved so far."
    blocks.append(Paragraph(coverage))
    if facts.vehicles is None:
        blocks += [Gap(), Paragraph(f"No headline: {facts.why}")]
    else:
        blocks += _headline_tables(facts)
    blocks += [Gap(), Paragraph(
        "This is the summary report: the headline, the run, and per vehicle the pilots' table and their paired "
        "differences. The full report (report.pdf) adds the metrics in detail, every flight drawn, the training "
        "and the failures." if summary_report else
        "What follows, per vehicle (PDF bookmarks lead to each part): every metric per pilot with its interval, "
        "the paired differences with the smallest difference the run could detect, success along task "
        "difficulty, the scenarios and episodes; then the classical pilot's tracker, the flights drawn, the "
        "training of the learned pilot and the failures.", size=9.0, style="italic")]
    return flow_pages("uam-compare report", blocks)


def _headline_tables(facts: TitleFacts) -> list[Block]:
    assert facts.vehicles is not None
    style = facts.style
    rates, pairs, small = [], [], []
    for vehicle, part in facts.vehicles.items():
        few: list[int] = []
        for m in style.sorted(list(part.pilots)):
            ms = part.pilots[m]
            rates.append((vehicle, style.label(m), str(ms.episodes), format_ci(ms.stats.get("success"), 100.0, 0),
                          format_ci(ms.stats.get("collision"), 100.0, 0)))
            if ms.episodes < MIN_INTERVAL_N and ms.episodes not in few:
                few.append(ms.episodes)
        if few:
            small.append(f"{vehicle} ({' or '.join(map(str, sorted(few)))})")
        for p in part.paired:
            succ, coll = p.stats.get("success"), p.stats.get("collision")
            pairs.append((vehicle, style.pair_label(p), str(p.episodes), format_ci(succ, 100.0, 0),
                          format_ci(coll, 100.0, 0), _called(succ), _called(coll)))
    out: list[Block] = [Gap(), TableBlock(
        ("vehicle", "pilot", "episodes", "success [%]", "collision [%]"), tuple(rates), 9.5,
        keep_columns=2, caption="Per vehicle and pilot: success and collisions, mean [Wilson 95 % interval]")]
    if pairs:
        out.append(TableBlock(
            ("vehicle", "pair (first − second)", "pairs", "success difference [% points]",
             "collision difference [% points]", "success: excludes 0", "collision: excludes 0"),
            tuple(pairs), 9.5, keep_columns=2,
            caption="Paired differences on the same tasks, mean [Newcombe 95 % interval]"))
    words = (f"Rates over each pilot's episodes; never pooled across vehicles. A paired difference is called (its "
             f"interval excludes 0) only from {MIN_INTERVAL_N} pairs up; below that the interval is shown and no "
             f"call is made. {facts.source[:1].upper()}{facts.source[1:]}")
    if small:
        words += (f" Fewer than {MIN_INTERVAL_N} episodes per pilot: {', '.join(small)}; such intervals are wide "
                  f"and tell the pilots apart only by a wide margin.")
    out.append(Paragraph(words, size=9.0))
    return out


def _called(st: PairedStat | None) -> str:
    if st is None or st.mean is None:
        return "n/a"
    if st.excludes_zero is None:
        return f"n/a (n < {MIN_INTERVAL_N})" if 0 < st.n < MIN_INTERVAL_N else "n/a"
    return "yes" if st.excludes_zero else "no"


def about_pages(facts: TitleFacts, compact: bool = False) -> list[Figure]:
    """"About this run": scenarios, pilots and their policies, notes, fairness and software versions (`compact`:
    the scenarios as one table, a row each, as the summary report has them)."""
    info = facts.info
    items: list[tuple[str, str]] = [("h", "Scenarios")]
    if not compact:
        for s in info.scenarios:
            items += _scenario_items(facts, s)
    items.append(("h", "Pilots"))
    for m, cfg in info.pilots.items():
        items.append(("p", f"{facts.label(m)} [{m}]: {cfg.description}"))
        for pol in cfg.policies:  # a pilot that flies policies: one per vehicle
            rate = f"; decides at {pol.decision_hz:g} Hz" if pol.decision_hz else ""
            who = f"for {pol.vehicle}: " if pol.vehicle else ""
            items.append(("p", f"    {who}policy {shown_path(pol.policy_dir, facts.run_dir, info.command)}{rate}"))
    if info.notes:  # e.g. cells left out, the pilots' decision rates
        items += [("h", "Notes"), *(("p", n) for n in info.notes)]
    items += [("h", "Fairness"), ("p", info.fairness or "n/a"),
              ("h", "Software versions"), ("p", " · ".join(f"{k} {v}" for k, v in info.versions.items()) or "n/a")]
    blocks = _compact(as_blocks(items))
    if compact:  # the table under the "Scenarios" heading
        blocks[2:2] = [TableBlock(("scenario", "vehicle", "map", "wind [m/s] (ENU)", "turbulence",
                                   "air density [kg/m³]", "sensing / map error", "episodes x seeds"),
                                  tuple(_scenario_row(s) for s in info.scenarios), 8.0)]
    return flow_pages("About this run", blocks)


def _scenario_row(s: ScenarioInfo) -> tuple[str, ...]:
    steady = "n/a" if s.wind.steady_enu_m_s is None else ", ".join(f"{v:g}" for v in s.wind.steady_enu_m_s)
    return (s.name, s.vehicle, s.map_name, steady, s.wind.turbulence or "n/a", _fmt(s.atmosphere.density_kg_m3, 3),
            f"{s.sensing} / {s.map_error}", f"{_num(s.episodes)} x {len(s.seeds)}")


def _compact(blocks: Sequence[Block]) -> list[Block]:
    """Smaller text than the default: the run's facts are many lines, and one page holds a default run's."""
    out: list[Block] = []
    for b in blocks:
        if isinstance(b, Paragraph):
            out.append(Paragraph(b.text, 8.5, b.style, b.weight, b.hanging_in))
        elif isinstance(b, Heading):
            out.append(Heading(b.text, 10.5))
        else:
            out.append(Gap(0.06) if isinstance(b, Gap) else b)
    return out


def _scenario_items(facts: TitleFacts, s: ScenarioInfo) -> list[tuple[str, str]]:
    atm, wind = s.atmosphere, s.wind
    steady = "n/a" if wind.steady_enu_m_s is None else str(list(wind.steady_enu_m_s))
    source = shown_path(s.source, facts.run_dir, facts.info.command) or "n/a"
    return [
        ("p", f"{s.name}: {s.description}"),
        ("p", f"    map {s.map_name} · vehicle {s.vehicle} ({s.vehicle_summary or 'n/a'}) · file {source}"),
        ("p", (f"    atmosphere: field elevation {_fmt(atm.elevation_m, 0)} m, ISA offset {_fmt(atm.isa_offset_k, 1)} "
               f"K, density {_fmt(atm.density_kg_m3, 3)} kg/m³ · wind: steady {steady} m/s (ENU), "
               f"{shear_words(wind.shear)}, turbulence {wind.turbulence or 'n/a'}")),
        ("p", (f"    sensing {s.sensing} · map error {s.map_error} (docs/sensing.md) · {_num(s.episodes)} episodes × "
               f"seeds {list(s.seeds)}; pilots {', '.join(facts.label(m) for m in s.pilots)}; physics "
               f"{_num(s.physics_hz)} Hz, control {_num(s.control_hz)} Hz"))]


def shear_words(shear: WindShear | None) -> str:
    """The steady wind's profile from run.json's wind.shear (absent in runs before it existed: uniform)."""
    if shear is None or shear.law is ShearLaw.UNIFORM:
        return "the same at every height"
    ref = _fmt(shear.reference_height_m, 0)
    if shear.law is ShearLaw.POWER:
        return f"given at {ref} m, power-law shear alpha {_fmt(shear.exponent, 2)}"
    return f"given at {ref} m, log-law shear z0 {_fmt(shear.roughness_m, 2)} m"


def _fmt(v: object, digits: int) -> str:
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "n/a"
    return f"{f:.{digits}f}" if math.isfinite(f) else "n/a"


def _num(v: float | None) -> str:
    """A recorded number as written short ("500" for 500.0), "n/a" when not recorded."""
    return "n/a" if v is None else f"{v:g}"
