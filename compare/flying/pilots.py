"""The pilots a comparison can fly, by name: how each is built, what it needs, how it is shown.

`PILOTS` is the one list of pilots. Scenario files are checked against it, the campaign builds
pilots through it, and run.json, the metrics, the report and its figures take labels, colours,
descriptions and the table order from it. Adding a pilot touches this file (one `PilotEntry`) and
the pilot itself (a `uam_fdm.pilot.Pilot`).

A builder is given a `BuildRequest` (the vehicle, the policy folder for it, the scenario's name for messages),
not the scenario: this module imports no scenario code, so the scenario loader, the episode files and the
metrics can all import it. The builders import their pilot's package only when called: reading a run folder,
or checking a scenario, needs neither PyTorch nor OMPL.

A pilot that is not ours flies as a plug-in, named wherever a pilot is (scenario files, --pilots,
--pilot) in one of two ways, resolved the same in every process (no registration step):

* `module:Class`, e.g. `mypkg.pilots:MyPilot`: imported from an installed package or PYTHONPATH;
* the name of an entry point in the `uam_compare.pilots` group of an installed distribution.

The object named is either a `Pilot` class (made with no arguments, one per process and vehicle;
the run shows its `label` class attribute, else its class name, and the first paragraph of its
docstring) or a ready `PilotEntry` (full control of label, colour, rates and report type).
"""
from __future__ import annotations

import functools
import importlib
import inspect
import numbers
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

from planners.report import ClassicalReport
from uam_fdm.pilot import Pilot, PilotReport
from uam_fdm.renamed import renamed
from uam_fdm.vehicle.params import VehicleParams


@dataclass(frozen=True)
class BuildRequest:
    """What a pilot is built for.

    Attributes:
        vehicle: the parameters of the vehicle it flies.
        vehicle_name: the vehicle as the scenario names it (a preset's name, else `vehicle.name`), for messages.
        source: the scenario it flies first (its file, or its generated set and name), for messages.
        policy: the policy folder for the vehicle, for a pilot that flies one (`PilotEntry.needs_policy`), else None.
    """

    vehicle: VehicleParams
    vehicle_name: str
    source: str
    policy: Path | None = None


Builder = Callable[[BuildRequest], Pilot]
"""Builds a pilot: (what it is built for) -> the pilot."""


@dataclass(frozen=True)
class PilotEntry:
    """One pilot of the comparison.

    Attributes:
        name: the pilot's name (scenario files, --pilots, file names, metrics.csv).
        label: its display name in the report, the figures and the viewer.
        color: its matplotlib colour on every page.
        description: what the pilot is (run.json, the report's Pilots section).
        given: what it is given and how it decides, one sentence for the run's fairness statement.
        build: makes the pilot (`Builder`); one built pilot flies all its cells in a process (one
            per vehicle when `needs_policy`).
        default: flown when a scenario file does not list its pilots.
        needs_policy: flies a trained policy folder per vehicle (`--policy`, or the one shipped for the
            vehicle); its cells are left out for a vehicle without one, and it decides at the policy's
            rate. Other pilots decide at each scenario's control rate.
        uses_torch: runs a PyTorch network (a worker process then keeps PyTorch to one thread).
        plans: always plans at reset, so its planning time is reported even when zero; for the others
            a zero planning time means none (metrics: NaN, "n/a").
        report_type: the type of its `episode_report()` (None: it reports nothing), which reads the
            report back from an episode file.
        wall_s_per_flight_s: upper bound of wall time per simulated second, one process (run estimates).
            The tests' tiny run (small quad) flies at 0.15 (ppo), 0.35 (rrt_mpc) and 0.08 (apf); the
            UAM's MPC is slower than real time.
    """

    name: str
    label: str
    color: str
    description: str
    given: str
    build: Builder
    default: bool = False
    needs_policy: bool = False
    uses_torch: bool = False
    plans: bool = False
    report_type: type[PilotReport] | None = None
    wall_s_per_flight_s: float = 1.0


# Each builder imports its pilot's package when called, so that reading a run folder or checking a scenario
# needs neither PyTorch (the learned pilot) nor OMPL (the classical one).
def _learned(request: BuildRequest) -> Pilot:
    from rl.pilots.learned import PolicyPilot, load_policy

    if request.policy is None:
        raise ValueError(f"{request.source}: no learned policy for vehicle {request.vehicle_name!r}")
    return PolicyPilot(load_policy(request.policy, request.vehicle))


def _classical(request: BuildRequest) -> Pilot:
    from planners.classical_pilot import ClassicalPilot

    return ClassicalPilot()


def _potential_field(request: BuildRequest) -> Pilot:
    from rl.pilots.potential_field import PotentialFieldPilot

    return PotentialFieldPilot()


PILOTS: dict[str, PilotEntry] = {entry.name: entry for entry in (
    PilotEntry(
        name="ppo", label="PPO policy", color="tab:orange",
        description="Learned pilot: policy network (2 x 128 tanh units, trained from scratch with PPO, no "
                    "demonstrations; see its provenance) choosing a 3D velocity command at its decision rate (held "
                    "between decisions) -> the vehicle's low-level velocity/attitude controller -> rotor speeds; "
                    "sees only its local observation (goal frame, horizontal rays and a roof-height map at its "
                    "vehicle's scale, the route around the buildings); one policy per vehicle, trained for it; "
                    "acts deterministically.",
        given="The learned pilot decides at its policy's decision rate (its command held by the same low-level "
              "controller in between), does not use the forecast turbulence level, sees only its observation (goal, "
              "a route around the buildings computed from the map at take-off, velocity, altitude, rays and a "
              "roof-height map of the buildings near it) and commands a velocity that the vehicle's low-level "
              "controller turns into rotor speeds. Below perfect sensing it observes its estimate and flies with "
              "the reduced lidar it was trained with (fewer channels and a coarser azimuth step than the "
              "scenario's part, rl.task.config.learned_lidar), whose scans it keeps in a height map over the "
              "prior map's.",
        build=_learned, default=True, needs_policy=True, uses_torch=True, wall_s_per_flight_s=0.2),
    PilotEntry(
        name="rrt_mpc", label="RRT* + MPC", color="tab:blue",
        description="Classical pilot: OMPL RRT* path (planned before take-off, timed) -> time-parameterised "
                    "reference -> CasADi NMPC (real-time iteration: one Gauss-Newton SQP step per decision, HPIPM) "
                    "commanding rotor speeds (through the wrench for many-rotor vehicles); clearance margins sized "
                    "from the vehicle's measured tracking error in the forecast turbulence and air density; "
                    "replanning on large tracking errors and when the MPC predicts it will come closer than its "
                    "margin.",
        given="The classical pilot decides at the scenario's control rate, sizes its clearance margins from the "
              "forecast turbulence level, plans on the whole map before take-off and when it replans (its planning "
              "time is reported separately) and commands rotor speeds through its MPC. Below perfect sensing it "
              "maps its lidar scans on its estimate into an occupancy octree fused with the prior map, widens its "
              "margins by 3 sigma of the estimate's position, and replans in flight when a sensed obstacle blocks "
              "its path or its uncertainty outgrows its margins, braking for a fixed replan budget meanwhile; "
              "with no path in what it knows it hovers and tries again.",
        build=_classical, default=True, plans=True, report_type=ClassicalReport, wall_s_per_flight_s=1.0),
    PilotEntry(
        name="apf", label="Potential field", color="tab:purple",
        description="Reactive baseline: artificial potential field (attraction along the straight line to the "
                    "goal, repulsion and a climb bias from the k = 5 nearest buildings within its range, slowing "
                    "near them; the learned pilot's evaluation baseline, rl/pilots/potential_field.py) choosing a "
                    "3D velocity command every control period -> the same low-level controller -> rotor speeds; no "
                    "planning, no memory, no learning.",
        given="The potential-field pilot decides at the scenario's control rate, sees only its position, the "
              "straight-line direction to the goal and the nearest points of the 5 nearest buildings within its "
              "range (30 m for the small quad, scaled with the learned pilot's clearance scale for other vehicles; "
              "exact distances from the map), uses neither the forecast turbulence level nor the air density, and "
              "commands a velocity that the vehicle's low-level controller turns into rotor speeds.",
        build=_potential_field, wall_s_per_flight_s=0.2),
)}

PILOT_NAMES: tuple[str, ...] = tuple(PILOTS)
"""Every registered pilot, in table order."""
DEFAULT_PILOTS: tuple[str, ...] = tuple(name for name, entry in PILOTS.items() if entry.default)
"""The pilots a scenario flies when its file does not list them."""
PLUGIN_GROUP = "uam_compare.pilots"
"""The entry-point group of plug-in pilots (`[project.entry-points."uam_compare.pilots"]`)."""
PLUGIN_WALL_S_PER_FLIGHT_S = 1.0  # run estimates for a plug-in that does not state its own
_REFERENCE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
_ENTRY_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")  # it names output files: the scenario-name rule
MAX_PLUGIN_NAME_BYTES = 78
"""Longest plug-in name (`module:Class` or an entry point's), in bytes. It names the episode files,
`<scenario>__ep000__<pilot>__s<seed>`, which `compare.results.trajectory.EpisodeKey` keeps within MAX_STEM_BYTES
(200) bytes: this leaves room for a scenario name of up to 100 characters (the loader's MAX_NAME_CHARS) and a seed
of up to 10 digits, so that a long name is refused when it is named, not when its first episode is saved."""
MAX_WALL_S_PER_FLIGHT_S = 1000.0  # a plug-in's wall time per simulated second: beyond it no cell limit means anything


def is_reference(name: str) -> bool:
    """`name` has the form `module:Class` (a plug-in named by its import path)."""
    return bool(_REFERENCE.match(name))


def pilot(name: str) -> PilotEntry:
    """The pilot `name`: a registered pilot, a plug-in `module:Class` or a plug-in entry point's name.

    Raises:
        ValueError: an unknown name (listing the registered ones and the plug-in forms), or a plug-in
            that cannot be imported or is not a pilot (saying why).
    """
    known = PILOTS.get(name)
    if known is not None:
        return known
    if is_reference(name):
        return _plugin(name)
    entry = _entry_point(name)
    if entry is not None:
        return _plugin_from_entry_point(entry.name, entry.value)
    plugins = sorted(e.name for e in metadata.entry_points(group=PLUGIN_GROUP))
    listed = f"; installed plug-ins: {', '.join(plugins)}" if plugins else ""
    raise ValueError(f"unknown pilot {name!r} (registered: {', '.join(PILOT_NAMES)}){listed}; a plug-in pilot is "
                     f"named as module:Class")


def registered(name: str) -> PilotEntry | None:
    """The registered pilot `name` (`PILOTS`), else None; never imports anything.

    Readers of a run folder (metrics, report, viewer, animation) use this, never `pilot`: a pilot name read
    from a data file may be `module:Class`, and resolving it would import (run) code the file names. What a
    reader needs of a plug-in (label, colour) comes from the run's own run.json (`compare.results.run_info`).
    """
    return PILOTS.get(name)


def _entry_point(name: str) -> metadata.EntryPoint | None:
    found = [e for e in metadata.entry_points(group=PLUGIN_GROUP) if e.name == name]
    return found[0] if found else None


def _check_name_length(name: str) -> None:
    """Refuse a plug-in name too long for the episode files it names (`MAX_PLUGIN_NAME_BYTES`), before any import."""
    size = len(name.encode())
    if size > MAX_PLUGIN_NAME_BYTES:
        raise ValueError(f"pilot {name[:40]!r}...: its name is {size} bytes long; at most {MAX_PLUGIN_NAME_BYTES} "
                         f"(it names the episode files, beside the scenario's name): use a shorter module path or "
                         f"class name, or an entry point")


@functools.cache  # one import and one entry per name and process (the module is cached by Python anyway)
def _plugin(reference: str) -> PilotEntry:
    _check_name_length(reference)
    module_name, _, attr = reference.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f"pilot {reference!r}: cannot import module {module_name!r} ({exc}); install its "
                         f"package or put its folder on PYTHONPATH") from exc
    except (Exception, SystemExit) as exc:  # its own code failed (a syntax error, an exception, sys.exit)
        raise ValueError(f"pilot {reference!r}: importing module {module_name!r} failed: {_failure(exc)}") from None
    obj: object = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"pilot {reference!r}: module {module_name!r} has no {attr!r}")
        obj = getattr(obj, part)
    return _entry_of(reference, reference, obj)


@functools.cache
def _plugin_from_entry_point(name: str, value: str) -> PilotEntry:
    if not _ENTRY_NAME.match(name) or "__" in name:
        raise ValueError(f"plug-in entry point {name!r} ({PLUGIN_GROUP}): a pilot name may only hold letters, "
                         f"digits, '_', '.' and '-', without '__' (it names output files)")
    _check_name_length(name)
    entry = _entry_point(name)
    assert entry is not None
    try:
        obj = entry.load()
    except (Exception, SystemExit) as exc:  # not installed, or its own code failed at import
        raise ValueError(f"pilot {name!r}: cannot load entry point {value!r} of {PLUGIN_GROUP} "
                         f"({_failure(exc)})") from None
    return _entry_of(name, value, obj)


def _failure(exc: BaseException) -> str:
    """What went wrong in a plug-in's own code, on one short line."""
    if isinstance(exc, SystemExit):
        return f"it called sys.exit({exc.code!r})"
    if isinstance(exc, SyntaxError):
        return f"syntax error in {exc.filename}, line {exc.lineno}: {exc.msg}"
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:200]}" + ("..." if len(text) > 200 else "")


MAX_LABEL_CHARS = 80
"""Longest label or colour name a plug-in may give (a label heads table columns and legends)."""
MAX_DESCRIPTION_CHARS = 2000


def _check_text(name: str, what: str, text: str, limit: int) -> str:
    """`text` unless it is too long or holds `$` (matplotlib reads `$...$` as mathematics, and a stray one
    fails the report after the flying); raises ValueError naming the plug-in and the attribute."""
    if len(text) > limit:
        raise ValueError(f"pilot {name!r}: its {what} is {len(text)} characters long ({text[:20]!r}...); at most "
                         f"{limit}")
    if "$" in text:
        raise ValueError(f"pilot {name!r}: its {what} {text[:60]!r} holds '$', which the report's figures would "
                         f"read as mathematics; leave it out")
    return text


def _check_color(name: str, color: str) -> str:
    """`color` ("" included: a colour is then chosen) unless matplotlib cannot draw it (ValueError)."""
    if not color:
        return color
    from matplotlib.colors import is_color_like  # matplotlib: only for a plug-in that gives a colour

    if len(color) > MAX_LABEL_CHARS or not is_color_like(color):
        raise ValueError(f"pilot {name!r}: color {color[:40]!r} is not a matplotlib colour (e.g. 'tab:green', "
                         f"'#1f77b4')")
    return color


def _check_constructible(name: str, cls: type) -> None:
    """A plug-in Pilot class is made with no arguments: say so now if its constructor needs some."""
    try:
        signature = inspect.signature(cls)
    except (TypeError, ValueError):  # a builtin or C class without a signature: made and checked at build
        return
    needed = [p.name for p in signature.parameters.values()
              if p.default is p.empty and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    if needed:
        raise ValueError(f"pilot {name!r}: {cls.__qualname__}() needs the argument(s) {', '.join(needed)}; a "
                         f"plug-in Pilot class is made with no arguments (or name a PilotEntry instead)")


def _check_named(name: str, cls: type) -> None:
    """A Pilot has a `name` (it labels the pilot's errors): a plug-in class declares it, as a class attribute (a
    string, or a property) or an annotation set in `__init__`; else every cell of it would fail."""
    annotated = any("name" in vars(k).get("__annotations__", {}) for k in cls.__mro__ if k is not Pilot)
    if not hasattr(cls, "name") and not annotated:
        raise ValueError(f"pilot {name!r}: {cls.__qualname__} has no `name`; a Pilot names itself (e.g. "
                         f"name = \"my_pilot\" in the class; uam_fdm.pilot.Pilot)")
    value = inspect.getattr_static(cls, "name", "")
    if not isinstance(value, str) and not hasattr(type(value), "__get__"):
        raise ValueError(f"pilot {name!r}: {cls.__qualname__}.name is {value!r:.40}, not a string")


def _check_wall_time(name: str, value: object) -> float:
    """`wall_s_per_flight_s` as a float, unless it is not a number in (0, MAX_WALL_S_PER_FLIGHT_S] (ValueError)."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        if 0.0 < float(value) <= MAX_WALL_S_PER_FLIGHT_S:  # NaN and infinity fail here too
            return float(value)
    raise ValueError(f"pilot {name!r}: wall_s_per_flight_s = {value!r:.40} is not a wall time per simulated "
                     f"second: a number in (0, {MAX_WALL_S_PER_FLIGHT_S:g}] (e.g. 1.0), or leave it out")


class _PluginBuilder:
    """Builds a plug-in `Pilot` class with no arguments and checks that it is one."""

    def __init__(self, name: str, cls: type) -> None:
        self.name, self.cls = name, cls

    def __call__(self, request: BuildRequest) -> Pilot:
        built = self.cls()
        if not isinstance(built, Pilot):
            raise ValueError(f"pilot {self.name!r}: {self.cls.__qualname__} is not a pilot: a Pilot has a name "
                             f"and the methods reset, act and episode_report (uam_fdm.pilot.Pilot)")
        return built


def _entry_of(name: str, source: str, obj: object) -> PilotEntry:
    """The `PilotEntry` of a plug-in object (a `PilotEntry`, or a `Pilot` class) named `name`."""
    if isinstance(obj, PilotEntry):
        _check_text(name, "label", obj.label, MAX_LABEL_CHARS)
        _check_text(name, "description", obj.description, MAX_DESCRIPTION_CHARS)
        return replace(obj, name=name, default=False, color=_check_color(name, obj.color),
                       wall_s_per_flight_s=_check_wall_time(name, obj.wall_s_per_flight_s))
    if not inspect.isclass(obj):
        raise ValueError(f"pilot {name!r}: {source} is a {type(obj).__name__}, not a Pilot class or a PilotEntry")
    missing = [m for m in ("reset", "act", "episode_report") if not callable(getattr(obj, m, None))]
    if missing:
        raise ValueError(f"pilot {name!r}: {obj.__qualname__} is not a pilot: it lacks {', '.join(missing)} "
                         f"(uam_fdm.pilot.Pilot)")
    _check_constructible(name, obj)
    _check_named(name, obj)
    label = _check_text(name, "label", str(getattr(obj, "label", obj.__name__)), MAX_LABEL_CHARS)
    doc = inspect.getdoc(obj) or ""
    description = str(getattr(obj, "description", "")) or doc.split("\n\n")[0].replace("\n", " ") or label
    description = _check_text(name, "description", description, MAX_DESCRIPTION_CHARS)
    own = _check_text(name, "given", str(getattr(obj, "given", "")), MAX_DESCRIPTION_CHARS)
    given = (f"The plug-in pilot {label} ({source}) decides at the scenario's control rate and is given what the "
             f"pilot interface carries: at take-off the vehicle's parameters and flight model, the building map, "
             f"the atmosphere and the forecast turbulence level, then the full vehicle state at each decision."
             + (f" {label}: {own}" if own else ""))
    report_type = getattr(obj, "report_type", None)
    return PilotEntry(
        name=name, label=label, color=_check_color(name, str(getattr(obj, "color", ""))),
        description=f"{description} (plug-in {source})",
        given=given, build=_PluginBuilder(name, obj), plans=bool(getattr(obj, "plans", False)),
        uses_torch=bool(getattr(obj, "uses_torch", False)),
        report_type=report_type if isinstance(report_type, type) else None,
        wall_s_per_flight_s=_check_wall_time(name, getattr(obj, "wall_s_per_flight_s", PLUGIN_WALL_S_PER_FLIGHT_S)))


def ordered(names: Iterable[str]) -> list[str]:
    """Pilot `names` without repeats, registered ones in table order first, then any others by name."""
    unique = set(names)
    return [m for m in PILOT_NAMES if m in unique] + sorted(unique - set(PILOT_NAMES))


def build(name: str, request: BuildRequest) -> Pilot:
    """Build the pilot `name` for `request` (its vehicle, and that vehicle's policy folder for a pilot that
    needs one).

    Raises:
        ValueError: an unknown pilot, or one that needs a policy and has none (naming the file).
    """
    built = pilot(name).build(request)
    if name in PILOTS and built.name != name:  # the pilot's own name labels its errors in the runner
        raise ValueError(f"the builder of pilot {name!r} made a pilot named {built.name!r}")
    return built


if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names
    def __getattr__(name: str) -> Any:
        """The old names (kept for one release, for plug-ins written against them): `PilotSpec` is `PilotEntry`,
        `METHODS` is `PILOT_NAMES`, `DEFAULT_METHODS` is `DEFAULT_PILOTS`; each with a warning (`uam_fdm.renamed`)."""
        return renamed(__name__, name, {"PilotSpec": "PilotEntry", "METHODS": "PILOT_NAMES",
                                        "DEFAULT_METHODS": "DEFAULT_PILOTS"})
