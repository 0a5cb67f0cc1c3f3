"""A run's provenance, `RUN_DIR/run.json`: what was flown, by which pilots, with which software.

`RunInfo` is written by `write_run_info` and read by `read_run_info`, nowhere else. The file's format
(version 1) is unchanged since the first runs; folders written by older versions read too: a key they
lack reads as empty (None, "", no entries), and a run that recorded the learned pilot's one policy as
`methods.ppo.policy_dir` (before policies per vehicle) reads as one `PolicyRecord` without a vehicle.
Optional keys (`fingerprints`, `suite`, a policy's `trained_air` and `trained_sensing`, a scenario's `sensing`,
`map_error`, `sensed` and `missing_fraction`) are written only when set, so rewriting an
older file gives it back byte for byte. The pilots stand under the key `methods` and the task set under `suite`,
their first names (`RunInfo.pilots`, `RunInfo.task_set` here): older readers and scripts look for them.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from compare.results.sensing_facts import SensedFacts, SensingEnvelope
from uam_fdm.air.shear import WindShear
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.strict import strict_json_loads

RUN_INFO_NAME = "run.json"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class AtmosphereInfo:
    """The scenario's air: field elevation [m MSL], ISA temperature offset [K], density at the field [kg/m³]."""

    elevation_m: float | None = None
    isa_offset_k: float | None = None
    density_kg_m3: float | None = None


@dataclass(frozen=True)
class WindInfo:
    """The scenario's wind: steady wind at its reference height (world ENU [m/s]), the turbulence level's
    name, and the shear (None in runs saved before shear existed: the same wind at every height)."""

    steady_enu_m_s: tuple[float, float, float] | None = None
    turbulence: str | None = None
    shear: WindShear | None = None


PRIOR_MAPS = "prior"
"""`RUN_DIR/maps/prior/<scenario>.yaml`: a scenario's prior map (the pilots'), where it differs from the city as it
stands (`maps/<scenario>.yaml`)."""


@dataclass(frozen=True)
class ScenarioInfo:
    """One scenario of a run as flown.

    Attributes:
        name, source, description: the scenario's name, file and free text.
        map_name: the city's name. vehicle: the vehicle's preset name; vehicle_summary: mass, rotors, radius.
        atmosphere, wind: the conditions flown.
        episodes: episode count; seeds: the seeds flown; pilots: the pilots flown, by name (the key "methods"
            in the file).
        physics_hz, control_hz: physics and control rates [Hz].
        sensing, map_error: the sensing level and map-error level flown ("perfect", "exact" in a run before either
            existed; a "+" marks overrides of the level's preset).
        sensed: what it sensed with (GNSS sky, lidar range); None at `perfect` or where not recorded.
        missing_fraction: the share of the city's buildings its prior map lacks (0 on an exact map; None where
            not recorded).
    """

    name: str
    source: str = ""
    description: str = ""
    map_name: str = ""
    vehicle: str = ""
    vehicle_summary: str = ""
    atmosphere: AtmosphereInfo = AtmosphereInfo()
    wind: WindInfo = WindInfo()
    episodes: int | None = None
    seeds: tuple[int, ...] = ()
    pilots: tuple[str, ...] = ()
    physics_hz: float | None = None
    control_hz: float | None = None
    sensing: str = "perfect"
    map_error: str = "exact"
    sensed: SensedFacts | None = None
    missing_fraction: float | None = 0.0


@dataclass(frozen=True)
class AirEnvelope:
    """The air a policy was trained in, as a run compares it with its scenarios' air.

    Attributes:
        density_altitude_m: the lowest and highest density altitude of its training fields [m] (the densest
            and thinnest corner of its elevation and ISA-offset ranges, `uam_fdm.air.atmosphere`).
        steady_wind_max_m_s: its top steady wind speed [m/s] (at the scenarios' wind reference height).
        turbulence: its turbulence levels (names).
    """

    density_altitude_m: tuple[float, float]
    steady_wind_max_m_s: float
    turbulence: tuple[str, ...]

    DENSITY_ALTITUDE_SLACK_M = 50.0
    """A field this close to the trained range counts as inside it [m] (a standard day at sea level is 0 m
    give or take the atmosphere tables' rounding)."""
    WIND_SLACK_M_S = 0.01
    """A steady wind this little over the trained top counts as inside it [m/s] (scenario files, the generated
    sets among them, give the wind's components to the centimetre per second, so its speed may land a few mm/s
    over a round step)."""

    def outside(self, density_altitude_m: float | None, steady_wind_m_s: float | None,
                turbulence: str | None) -> tuple[str, ...]:
        """Why air lies outside this envelope, one phrase per reason ("density altitude 1500 m", "steady wind
        6.0 m/s", "moderate turbulence"; empty: inside; an argument None: not recorded, not compared).

        Args:
            density_altitude_m: the field's density altitude [m].
            steady_wind_m_s: the steady wind speed at the reference height [m/s].
            turbulence: the turbulence level's name.
        """
        why = []
        lo, hi = self.density_altitude_m
        if density_altitude_m is not None and not (lo - self.DENSITY_ALTITUDE_SLACK_M <= density_altitude_m
                                                   <= hi + self.DENSITY_ALTITUDE_SLACK_M):
            why.append(f"density altitude {round(density_altitude_m):d} m")
        if steady_wind_m_s is not None and steady_wind_m_s > self.steady_wind_max_m_s + self.WIND_SLACK_M_S:
            why.append(f"steady wind {steady_wind_m_s:.1f} m/s")
        if turbulence is not None and turbulence not in self.turbulence:
            why.append(f"{turbulence} turbulence")
        return tuple(why)

    def describe(self) -> str:
        """The envelope in words: "density altitude 0 to 4100 m, steady wind to 8 m/s, none/light turbulence"."""
        lo, hi = self.density_altitude_m
        return (f"density altitude {round(lo):d} to {round(hi):d} m, steady wind to {self.steady_wind_max_m_s:g} m/s, "
                f"{'/'.join(self.turbulence)} turbulence")


@dataclass(frozen=True)
class PolicyRecord:
    """A learned pilot's policy a run flew: the vehicle it was trained for (None in runs saved before
    policies per vehicle), its folder, its decision rate [Hz] (None where not recorded), the air it was
    trained in and the sensing and map error it was trained across (None in runs saved before each was
    recorded)."""

    vehicle: str | None
    policy_dir: str
    decision_hz: float | None = None
    envelope: AirEnvelope | None = None
    sensing: SensingEnvelope | None = None


@dataclass(frozen=True)
class PilotInfo:
    """A pilot as the run describes it: display label, description, (the learned pilot) its policies, and its
    own matplotlib colour ("" where not recorded: a registered pilot's is the registry's). Readers take a
    plug-in's label and colour from here and never import the plug-in."""

    label: str
    description: str = ""
    policies: tuple[PolicyRecord, ...] = ()
    color: str = ""


@dataclass(frozen=True)
class TaskSetInfo:
    """The published task set a run's scenarios come from (`compare.scenarios.benchmark`).

    Attributes:
        name: the set's name (e.g. "benchmark-quick").
        version: the generator's version and a short hash of the generated tasks (cities, legs, air): any
            change to what the generator makes changes it.
        description: one line on the task distribution.
    """

    name: str
    version: str
    description: str = ""


@dataclass(frozen=True)
class RunInfo:
    """The contents of `run.json`.

    Attributes:
        created_utc: creation time, ISO 8601 UTC ("2026-11-21T08:00:00Z").
        command: the command line that made the run.
        scenarios: the scenarios, in run order.
        notes: remarks for the report (cells left out, the pilots' decision rates).
        pilots: the pilots by name, in run order (the key "methods" in the file).
        versions: software versions by package name.
        fairness: the fairness statement.
        fingerprints: hashes of the inputs (`compare.scenarios.fingerprint.run_fingerprints`; None in runs saved before
            they were recorded).
        task_set: the published task set the scenarios come from, under the key "suite" in the file (None:
            scenario files, or a run saved before task sets were recorded).
        format_version: the file format.
    """

    created_utc: str = ""
    command: str = ""
    scenarios: tuple[ScenarioInfo, ...] = ()
    notes: tuple[str, ...] = ()
    pilots: Mapping[str, PilotInfo] = field(default_factory=dict)
    versions: Mapping[str, str] = field(default_factory=dict)
    fairness: str = ""
    fingerprints: Mapping[str, Any] | None = None
    task_set: TaskSetInfo | None = None
    format_version: int = FORMAT_VERSION

    def label(self, pilot: str) -> str:
        """The pilot's display label (its name when the run does not describe it)."""
        m = self.pilots.get(pilot)
        return m.label if m is not None else pilot

    def colors(self) -> dict[str, str]:
        """The colours the run recorded, by pilot (plug-ins that stated one)."""
        return {name: m.color for name, m in self.pilots.items() if m.color}

    def run_order(self, more_pilots: Iterable[str] = ()) -> tuple[list[str], list[str]]:
        """The vehicles of its scenarios and its pilots, then `more_pilots` (e.g. those of metrics rows), each
        once, in run order."""
        return (list(dict.fromkeys(s.vehicle for s in self.scenarios)),
                list(dict.fromkeys([*self.pilots, *more_pilots])))

    def scenario(self, name: str) -> ScenarioInfo | None:
        """The scenario named `name`, or None."""
        return next((s for s in self.scenarios if s.name == name), None)

    def policies(self, pilot: str = "ppo") -> tuple[PolicyRecord, ...]:
        """The policies the run records for `pilot` (none for a pilot without one)."""
        m = self.pilots.get(pilot)
        return m.policies if m is not None else ()


# ---- writing ----------------------------------------------------------------------------------------------
def write_run_info(info: RunInfo, run_dir: Path) -> Path:
    """Write `RUN_DIR/run.json` atomically (indent 2); returns its path."""
    return write_text_atomic(Path(run_dir) / RUN_INFO_NAME, json.dumps(run_info_to_json(info), indent=2) + "\n",
                             root=run_dir)


def run_info_to_json(info: RunInfo) -> dict[str, Any]:
    """`info` as the plain data of `run.json`, keys in the file's order."""
    out: dict[str, Any] = {
        "format_version": info.format_version, "created_utc": info.created_utc, "command": info.command,
        "scenarios": [_scenario_json(s) for s in info.scenarios], "notes": list(info.notes),
        "methods": {m: _pilot_json(c) for m, c in info.pilots.items()},  # the key keeps its first name
        "versions": dict(info.versions), "fairness": info.fairness,
    }
    if info.fingerprints is not None:
        out["fingerprints"] = info.fingerprints
    if info.task_set is not None:  # the key keeps its first name: older readers and scripts look for it
        out["suite"] = {"name": info.task_set.name, "version": info.task_set.version,
                        "description": info.task_set.description}
    return out


def _scenario_json(s: ScenarioInfo) -> dict[str, Any]:
    atm, wind = s.atmosphere, s.wind
    wind_json: dict[str, Any] = {"steady_enu_m_s": None if wind.steady_enu_m_s is None else list(wind.steady_enu_m_s),
                                 "turbulence": wind.turbulence}
    if wind.shear is not None:
        wind_json["shear"] = wind.shear.to_dict()
    return {
        "name": s.name, "source": s.source, "description": s.description, "map_name": s.map_name,
        "vehicle": s.vehicle, "vehicle_summary": s.vehicle_summary,
        "atmosphere": {"elevation_m": atm.elevation_m, "isa_offset_k": atm.isa_offset_k,
                       "density_kg_m3": atm.density_kg_m3},
        "wind": wind_json, "episodes": s.episodes, "seeds": list(s.seeds), "methods": list(s.pilots),
        "physics_hz": s.physics_hz, "control_hz": s.control_hz,
        **({} if s.sensing == "perfect" else {"sensing": s.sensing}),  # an older run's file rewrites byte for byte
        **({} if s.map_error == "exact" else {"map_error": s.map_error}),
        **({} if s.sensed is None else {"sensed": {"gnss_urban_canyon": s.sensed.gnss_urban_canyon,
                                                   "gnss_max_outage_s": s.sensed.gnss_max_outage_s,
                                                   "lidar_range_m": s.sensed.lidar_range_m}}),
        # beside a map error only (an exact map's is 0), so that an older run's file rewrites byte for byte
        **({} if s.map_error == "exact" or s.missing_fraction is None else {"missing_fraction": s.missing_fraction}),
    }


def _pilot_json(m: PilotInfo) -> dict[str, Any]:
    out: dict[str, Any] = {"label": m.label, "description": m.description}
    if m.color:  # written only when set: an older file rewrites byte for byte
        out["color"] = m.color
    if m.policies:
        out["policies"] = [_policy_json(p) for p in m.policies]
    return out


def _policy_json(p: PolicyRecord) -> dict[str, Any]:
    out: dict[str, Any] = {"vehicle": p.vehicle, "policy_dir": p.policy_dir, "decision_hz": p.decision_hz}
    if p.envelope is not None:  # only when recorded: an older file rewrites byte for byte
        e = p.envelope
        out["trained_air"] = {"density_altitude_m": list(e.density_altitude_m),
                              "steady_wind_max_m_s": e.steady_wind_max_m_s, "turbulence": list(e.turbulence)}
    if p.sensing is not None:
        se = p.sensing
        out["trained_sensing"] = {"sensed": se.sensed, "gnss_urban_canyon": se.gnss_urban_canyon,
                                  "gnss_max_outage_s": se.gnss_max_outage_s, "lidar_range_m": se.lidar_range_m,
                                  "missing_fraction_max": se.missing_fraction_max}
    return out


# ---- reading ----------------------------------------------------------------------------------------------
def read_run_info(run_dir: Path) -> RunInfo:
    """Read `RUN_DIR/run.json` (any version this tool wrote; see the module docstring).

    Raises:
        ValueError: no run.json, not readable JSON, or a value of the wrong kind, naming the file and the key.
    """
    path = Path(run_dir) / RUN_INFO_NAME
    if not path.is_file():
        raise ValueError(f"{run_dir}: not a run folder (no {RUN_INFO_NAME})")
    try:
        data = strict_json_loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from exc
    return run_info_from_json(data, str(path))


def run_info_from_json(data: Any, where: str) -> RunInfo:
    """`RunInfo` from the plain data of a run.json (`where`: the file, for messages)."""
    r = _Reader(where)
    top = r.mapping(data, "<root>")
    version = r.integer(top, "format_version", "format_version")
    if version is not None and version != FORMAT_VERSION:
        raise ValueError(f"{where}: format_version {version}, expected {FORMAT_VERSION}")
    fingerprints = top.get("fingerprints")
    return RunInfo(
        created_utc=r.text(top, "created_utc", "created_utc"), command=r.text(top, "command", "command"),
        scenarios=tuple(_scenario_info(r, s, f"scenarios[{i}]")
                        for i, s in enumerate(r.sequence(top, "scenarios", "scenarios"))),
        notes=tuple(str(n) for n in r.sequence(top, "notes", "notes")),
        pilots={str(m): _pilot_info(r, c, str(m), f"methods.{m}")
                 for m, c in r.mapping(top.get("methods"), "methods").items()},
        versions={str(k): str(v) for k, v in r.mapping(top.get("versions"), "versions").items()},
        fairness=r.text(top, "fairness", "fairness"),
        fingerprints=None if fingerprints is None else r.mapping(fingerprints, "fingerprints"),
        task_set=_task_set_info(r, top.get("suite"), "suite"),
    )


def _task_set_info(r: _Reader, value: Any, key: str) -> TaskSetInfo | None:
    if value is None:
        return None
    s = r.mapping(value, key)
    return TaskSetInfo(r.text(s, "name", f"{key}.name"), r.text(s, "version", f"{key}.version"),
                       r.text(s, "description", f"{key}.description"))


def _scenario_info(r: _Reader, value: Any, key: str) -> ScenarioInfo:
    s = r.mapping(value, key)
    atm = r.mapping(s.get("atmosphere"), f"{key}.atmosphere")
    wind = r.mapping(s.get("wind"), f"{key}.wind")
    if isinstance(s.get("episodes"), list):  # tolerated: the episodes listed rather than counted
        s = {**s, "episodes": len(s["episodes"])}
    map_error = _level(r.text(s, "map_error", f"{key}.map_error"), "exact")
    return ScenarioInfo(
        name=r.text(s, "name", f"{key}.name"), source=r.text(s, "source", f"{key}.source"),
        description=r.text(s, "description", f"{key}.description"),
        map_name=r.text(s, "map_name", f"{key}.map_name"), vehicle=r.text(s, "vehicle", f"{key}.vehicle"),
        vehicle_summary=r.text(s, "vehicle_summary", f"{key}.vehicle_summary"),
        atmosphere=AtmosphereInfo(*(r.number(atm, k, f"{key}.atmosphere.{k}")
                                    for k in ("elevation_m", "isa_offset_k", "density_kg_m3"))),
        wind=WindInfo(r.vector3(wind, "steady_enu_m_s", f"{key}.wind.steady_enu_m_s"),
                      r.text(wind, "turbulence", f"{key}.wind.turbulence") or None,
                      r.shear(wind.get("shear"), f"{key}.wind.shear")),
        episodes=r.integer(s, "episodes", f"{key}.episodes"),
        seeds=tuple(r.entry_integer(v, f"{key}.seeds[{i}]")
                    for i, v in enumerate(r.sequence(s, "seeds", f"{key}.seeds"))),
        pilots=tuple(str(m) for m in r.sequence(s, "methods", f"{key}.methods")),
        physics_hz=r.number(s, "physics_hz", f"{key}.physics_hz"),
        control_hz=r.number(s, "control_hz", f"{key}.control_hz"),
        sensing=_level(r.text(s, "sensing", f"{key}.sensing"), "perfect"),
        map_error=map_error,
        sensed=_sensed(r, s.get("sensed"), f"{key}.sensed"),
        missing_fraction=0.0 if map_error == "exact" else r.number(s, "missing_fraction", f"{key}.missing_fraction"),
    )


def _sensed(r: _Reader, value: Any, key: str) -> SensedFacts | None:
    if value is None:
        return None
    d = r.mapping(value, key)
    outage, lidar = (r.number(d, k, f"{key}.{k}") for k in ("gnss_max_outage_s", "lidar_range_m"))
    if outage is None or lidar is None:
        raise r.fail(key, value, "gnss_urban_canyon, gnss_max_outage_s and lidar_range_m")
    return SensedFacts(r.flag(d, "gnss_urban_canyon", f"{key}.gnss_urban_canyon"), outage, lidar)


def _level(text: str, default: str) -> str:
    """A level's label from run.json: a short plain word with an optional "+" (else the default: a file's text
    never becomes a label)."""
    return text if re.fullmatch(r"[a-z]{1,16}\+?", text or "") else default


def _pilot_info(r: _Reader, value: Any, pilot: str, key: str) -> PilotInfo:
    c = r.mapping(value, key)
    if c.get("policies") is not None:
        policies = tuple(_policy(r, p, f"{key}.policies[{i}]")
                         for i, p in enumerate(r.sequence(c, "policies", f"{key}.policies")))
    elif c.get("policy_dir"):  # before policies per vehicle: one policy, its vehicle not recorded
        policies = (PolicyRecord(None, r.text(c, "policy_dir", f"{key}.policy_dir"),
                                 r.number(c, "decision_hz", f"{key}.decision_hz")),)
    else:
        policies = ()
    return PilotInfo(r.text(c, "label", f"{key}.label") or pilot, r.text(c, "description", f"{key}.description"),
                      policies, r.text(c, "color", f"{key}.color"))


def _policy(r: _Reader, value: Any, key: str) -> PolicyRecord:
    p = r.mapping(value, key)
    return PolicyRecord(r.text(p, "vehicle", f"{key}.vehicle") or None, r.text(p, "policy_dir", f"{key}.policy_dir"),
                        r.number(p, "decision_hz", f"{key}.decision_hz"),
                        _envelope(r, p.get("trained_air"), f"{key}.trained_air"),
                        _sensing_envelope(r, p.get("trained_sensing"), f"{key}.trained_sensing"))


def _envelope(r: _Reader, value: Any, key: str) -> AirEnvelope | None:
    if value is None:
        return None
    e = r.mapping(value, key)
    da = [r.entry_number(v, f"{key}.density_altitude_m[{i}]")
          for i, v in enumerate(r.sequence(e, "density_altitude_m", f"{key}.density_altitude_m"))]
    wind = r.number(e, "steady_wind_max_m_s", f"{key}.steady_wind_max_m_s")
    if len(da) != 2 or wind is None:
        raise r.fail(key, value, "density_altitude_m [low, high] and steady_wind_max_m_s")
    return AirEnvelope((da[0], da[1]), wind, tuple(str(t) for t in r.sequence(e, "turbulence", f"{key}.turbulence")))


def _sensing_envelope(r: _Reader, value: Any, key: str) -> SensingEnvelope | None:
    if value is None:
        return None
    e = r.mapping(value, key)
    outage, missing = (r.number(e, k, f"{key}.{k}") for k in ("gnss_max_outage_s", "missing_fraction_max"))
    if outage is None or missing is None:
        raise r.fail(key, value, "gnss_max_outage_s and missing_fraction_max")
    return SensingEnvelope(r.flag(e, "sensed", f"{key}.sensed"), r.flag(e, "gnss_urban_canyon",
                                                                         f"{key}.gnss_urban_canyon"),
                           outage, r.number(e, "lidar_range_m", f"{key}.lidar_range_m"), missing)


@dataclass(frozen=True)
class _Reader:
    """Typed reads of run.json values: absent or null reads as empty (None, "", no entries); a value of the
    wrong kind raises ValueError naming the file, the key and the value."""

    where: str

    def fail(self, key: str, value: Any, expected: str) -> ValueError:
        return ValueError(f"{self.where}: {key}: expected {expected}, got {value!r}")

    def mapping(self, value: Any, key: str) -> Mapping[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, Mapping):
            raise self.fail(key, value, "a JSON object")
        return value

    def sequence(self, d: Mapping[str, Any], name: str, key: str) -> list[Any]:
        value = d.get(name)
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.fail(key, value, "a JSON list")
        return value

    def text(self, d: Mapping[str, Any], name: str, key: str) -> str:
        value = d.get(name)
        if value is None:
            return ""
        if not isinstance(value, str):
            raise self.fail(key, value, "a string")
        return value

    def number(self, d: Mapping[str, Any], name: str, key: str) -> float | None:
        value = d.get(name)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, value, "a finite number")
        return float(value)

    def flag(self, d: Mapping[str, Any], name: str, key: str) -> bool:
        """A boolean (absent or null reads as False)."""
        value = d.get(name)
        if value is None:
            return False
        if not isinstance(value, bool):
            raise self.fail(key, value, "true or false")
        return value

    def integer(self, d: Mapping[str, Any], name: str, key: str) -> int | None:
        value = d.get(name)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, value, "an integer")
        return value

    def entry_number(self, value: Any, key: str) -> float:
        """A number entry of a list (null is not one)."""
        number = self.number({"entry": value}, "entry", key)
        if number is None:
            raise self.fail(key, value, "a finite number")
        return number

    def entry_integer(self, value: Any, key: str) -> int:
        """An integer entry of a list (null is not one: a list has no absent entries)."""
        number = self.integer({"entry": value}, "entry", key)
        if number is None:
            raise self.fail(key, value, "an integer")
        return number

    def vector3(self, d: Mapping[str, Any], name: str, key: str) -> tuple[float, float, float] | None:
        values = self.sequence(d, name, key)
        if name not in d or d[name] is None:
            return None
        numbers = [self.number({name: v}, name, f"{key}[{i}]") for i, v in enumerate(values)]
        if len(numbers) != 3 or any(v is None for v in numbers):
            raise self.fail(key, d[name], "3 numbers")
        return (numbers[0], numbers[1], numbers[2])  # type: ignore[return-value]

    def shear(self, value: Any, key: str) -> WindShear | None:
        if value is None:
            return None
        d = self.mapping(value, key)
        try:
            return WindShear(**{k: d[k] for k in ("law", "reference_height_m", "exponent", "roughness_m")
                                if d.get(k) is not None})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{self.where}: {key}: {exc}") from None
