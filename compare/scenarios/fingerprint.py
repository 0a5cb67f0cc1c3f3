"""What a run's cells were computed from, as hashes: `--resume` completes a run only with the same inputs.

`run_fingerprints` hashes, per scenario, its resolved content (map, vehicle parameters, atmosphere,
wind and rates, episodes), the files of each policy folder flown (one per vehicle, for the pilots that fly a
policy: `compare.flying.pilots.PilotEntry.needs_policy`), and the code version; the run
stores them in `run.json` under "fingerprints". `check_resume` reads a folder (never writes) and
refuses, with every difference listed, a folder that is not a run of this tool or whose saved inputs
differ from the ones given now: finished episodes are never mixed with episodes of other inputs.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping, Sequence
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from compare.results.run_info import RUN_INFO_NAME, read_run_info
from compare.scenarios.scenario import Scenario
from rl.policies.folder import FLYING_FILES
from uam_fdm.files.version import code_version

# Words for the parts of a scenario's fingerprint, in the error that lists differences.
SCENARIO_PARTS = {"map": "map (buildings, bounds, no-fly zones)", "vehicle": "vehicle parameters",
                  "conditions": "atmosphere, wind or rates", "episodes": "episodes (start, goal, radius, timeout)",
                  "sensing": "sensing (sensors, latency)"}


def _plain(value: Any) -> Any:
    """`value` as JSON-able plain data with exact floats (dataclasses by type and field, arrays as lists)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"_type": type(value).__name__,
                **{f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    if isinstance(value, Enum):
        return _plain(value.value)
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (float, np.floating)):
        return repr(float(value))  # repr round-trips exactly, NaN and inf included
    if isinstance(value, np.integer):
        return int(value)
    return value


def _digest(value: Any) -> str:
    """A short stable hash of `value`'s plain data."""
    return hashlib.sha256(json.dumps(_plain(value), sort_keys=True).encode()).hexdigest()[:16]


def scenario_fingerprint(sc: Scenario) -> dict[str, str]:
    """Hashes of what a scenario's cells are flown from, one per part (keys of SCENARIO_PARTS).

    Names, descriptions and file paths are left out (they do not change a flight); seeds and pilots
    too: they name cells (the episode files), so a resume with more seeds only adds cells. The prior map (when it
    differs from the city) joins the map's hash and "sensing" is a part only when the vehicle senses less than
    perfectly, so a scenario without map error or sensing keeps the hashes it had before they existed.
    """
    city = sc.city
    world = [list(city.buildings), city.bounds_min_m, city.bounds_max_m, list(city.no_fly)]
    if sc.prior_map is not city:
        world.append(list(sc.prior_map.buildings))
    out = {
        "map": _digest(world),
        "vehicle": sc.vehicle.fingerprint(),
        "conditions": _digest([sc.atmosphere, sc.wind, sc.physics_hz, sc.control_hz]),
        "episodes": _digest([[ep.index, ep.task] for ep in sc.episodes]),
    }
    if not sc.sensing.perfect:
        out["sensing"] = _digest(sc.sensing)
    return out


def policy_fingerprint(folder: Path) -> dict[str, str]:
    """SHA-256 of each of the files a policy folder's pilot flies with (`rl.policies.folder.FLYING_FILES`;
    "missing" for an absent one)."""
    out = {}
    for name in FLYING_FILES:
        path = Path(folder) / name
        out[name] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"
    return out


def run_fingerprints(scenarios: Sequence[Scenario], policies: Mapping[str, Path]) -> dict:
    """The "fingerprints" block of run.json: code, each scenario, and the policy folder flown for each
    vehicle (`policies`: folder by vehicle name; empty when no pilot that flies a policy is flown)."""
    out: dict = {"code": code_version(), "scenarios": {sc.name: scenario_fingerprint(sc) for sc in scenarios}}
    if policies:
        out["policies"] = {v: {"folder": str(Path(d).resolve()), "files": policy_fingerprint(d)}
                           for v, d in sorted(policies.items())}
    return out


def fingerprint_differences(saved: Mapping, now: Mapping) -> list[str]:
    """Every way the saved fingerprints differ from `now`'s, one short phrase each (empty: the same)."""
    diffs = []
    a, b = saved.get("scenarios") or {}, now.get("scenarios") or {}
    if set(a) != set(b):
        diffs.append(f"scenarios: saved {', '.join(sorted(a)) or 'none'}, now {', '.join(sorted(b)) or 'none'}")
    for name in sorted(set(a) & set(b)):
        sa, sb = a[name] or {}, b[name] or {}
        parts = [SCENARIO_PARTS.get(k, k) for k in sorted(set(sa) | set(sb)) if sa.get(k) != sb.get(k)]
        if parts:
            diffs.append(f"scenario {name}: {', '.join(parts)} changed")
    saved_p, now_p = saved.get("policies") or {}, now.get("policies") or {}
    for vehicle in sorted(set(saved_p) & set(now_p)):  # a vehicle that flew no policy before may start to
        pa, pb = saved_p[vehicle] or {}, now_p[vehicle] or {}
        fa, fb = pa.get("files") or {}, pb.get("files") or {}
        changed = [f for f in sorted(set(fa) | set(fb)) if fa.get(f) != fb.get(f)]
        if changed:
            diffs.append(f"{vehicle} policy {', '.join(changed)} differ (saved from {pa.get('folder')}, "
                         f"now {pb.get('folder')})")
    ca, cb = saved.get("code") or {}, now.get("code") or {}
    if ca != cb:
        diffs.append(f"code version: saved {_code_words(ca)}, now {_code_words(cb)}")
    return diffs


def _code_words(code: Mapping) -> str:
    commit = code.get("commit")
    return f"uam-compare {code.get('uam-compare')}" + (f" commit {commit[:12]}" if commit else " (no commit)")


def check_resume(out: Path, now: dict, flown: Mapping[str, tuple[tuple[int, ...], tuple[str, ...]]] | None = None
                 ) -> dict:
    """Refuse to resume into `out` unless it is a run of this tool saved from the inputs in `now`, flying the
    same seeds and pilots per scenario as the saved run (`flown`: scenario name -> (seeds, pilots); run.json
    describes one command's cells, so a resume may not mix in another's).

    Reads only: a refused folder is left byte for byte as it was. A missing or empty folder is a fresh start.

    Returns:
        The fingerprints to save: `now`, keeping the saved policy of each vehicle that flies no policy
        this time (its episodes are still in the folder, and a later resume that flies the policy for
        that vehicle must match them).

    Raises:
        ValueError: `out` holds files but no run.json, an unreadable run.json, one without fingerprints,
            or one whose fingerprints differ from `now` (every difference listed), naming the folder.
    """
    out = Path(out)
    if not out.exists() or not any(out.iterdir()):
        return now
    path = out / RUN_INFO_NAME
    if not path.is_file():
        raise ValueError(f"{out}: cannot resume: not a run folder of uam-compare (no {RUN_INFO_NAME}); nothing was "
                         f"written (give --out a new or empty folder)")
    try:
        saved = read_run_info(out)
    except ValueError as exc:  # the message names the file
        raise ValueError(f"{out}: cannot resume: {exc}; nothing was written") from exc
    if not saved.scenarios:
        raise ValueError(f"{path}: cannot resume: not a run.json of uam-compare (it lists no scenarios); nothing "
                         f"was written")
    fps = saved.fingerprints
    if fps is None:
        # Refused rather than trusted: without the saved hashes nothing says whether the scenarios
        # (maps are kept only to 1 cm), the policy (kept only by path) or the code changed since.
        raise ValueError(f"{out}: cannot resume: the run predates input fingerprints (its run.json has none), so "
                         f"its scenarios, vehicle, policy and code cannot be compared with these; nothing was "
                         f"written (fly into a new folder; `uam-compare report` still reports this one)")
    diffs = fingerprint_differences(fps, now)
    asked = flown or {}
    for info in saved.scenarios if asked else ():
        seeds, names = asked.get(info.name, (info.seeds, info.pilots))
        if tuple(seeds) != tuple(info.seeds):
            diffs.append(f"scenario {info.name}: seeds saved {list(info.seeds)}, now {list(seeds)} (--seeds)")
        if tuple(names) != tuple(info.pilots):
            diffs.append(f"scenario {info.name}: pilots saved {', '.join(info.pilots)}, now {', '.join(names)} "
                         f"(--pilots, --pilot)")
    if diffs:
        raise ValueError(f"{out}: cannot resume: the inputs differ from the saved run's: {'; '.join(diffs)}; "
                         f"nothing was written (fly into a new folder)")
    saved_policies = fps.get("policies")
    saved_p = saved_policies if isinstance(saved_policies, dict) else {}
    merged = {**saved_p, **(now.get("policies") or {})}
    return {**now, "policies": merged} if merged else now
