"""The scenario key `sensing:`: a sensing level by name, or a level with some of its figures changed.

    sensing: degraded
    sensing: {preset: nominal, latency_s: 0.05, lidar: {dropout: 0.1}, gnss: {urban_canyon: true}}

A mapping's `preset` defaults to `nominal`; each section (`imu`, `baro`, `gnss`, `heading`, `lidar`) takes the
fields of its spec in `uam_fdm.sensing.specs` (all but `part`), in the spec's units. Every value is checked here,
before anything is built: a bad one raises `ConfigError` naming the file, the dotted key and the value. The lidar's
rays per scan are bounded (`MAX_LIDAR_RAYS_PER_SCAN`) from its channels and resolution alone, so an absurd lidar is
refused before a ray is allocated.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any

from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import boolean, mapping, non_negative, number_in_range, numbers
from uam_fdm.sensing.specs import LEVELS, SensingConfig, sensing_preset

DEFAULT_OVERRIDE_PRESET = "nominal"  # the level a mapping without `preset` starts from
MAX_LIDAR_RAYS_PER_SCAN = 300_000  # a 128-channel lidar at 2048 columns is 262,144
MAX_RATE_HZ = 10_000.0  # IMU, barometer, heading (the physics' own cap)
MAX_SCAN_RATE_HZ = 100.0  # GNSS fixes and lidar scans (real parts: 25 Hz and 20 Hz at most)
MAX_LATENCY_S = 1.0
MAX_OUTAGE_S = 600.0
MAX_CORRELATION_TIME_S = 86_400.0
MAX_SATELLITES = 100
MIN_FIX_SATELLITES = 4  # a 3D fix solves for position and clock: four unknowns
MAX_RANGE_M = 10_000.0

_Check = Callable[[Any, str, str], Any]


def _in(low: float, high: float, unit: str, open_low: bool = False) -> _Check:
    return lambda v, s, k: number_in_range(v, (low, high), unit, s, k, open_low=open_low)


def _integer(low: int, high: int) -> _Check:
    def check(value: Any, source: str, key: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ConfigError(source, key, f"must be an integer in [{low}, {high}], got {value!r}")
        return value
    return check


def _fov(value: Any, source: str, key: str) -> tuple[float, float]:
    low, high = numbers(value, 2, source, key, what="[lowest, highest] elevation in degrees")
    if not -90.0 <= low <= high <= 90.0:
        raise ConfigError(source, key, f"must be [lowest, highest] with -90 <= lowest <= highest <= 90 deg, "
                                       f"got {value!r}")
    return low, high


_RATE = _in(0.0, MAX_RATE_HZ, "Hz", open_low=True)
_SCAN_RATE = _in(0.0, MAX_SCAN_RATE_HZ, "Hz", open_low=True)
_CORRELATION = _in(0.0, MAX_CORRELATION_TIME_S, "s", open_low=True)
_PROBABILITY = _in(0.0, 1.0, "probability")
_ANGLE_SIGMA = _in(0.0, math.pi, "rad")

# Every field a scenario may set, with its check (`part` names a real part: not a figure to change).
_FIELDS: dict[str, dict[str, _Check]] = {
    "imu": {"rate_hz": _RATE, "accel_noise_density_m_s2_rthz": non_negative,
            "gyro_noise_density_rad_s_rthz": non_negative, "accel_bias_walk_m_s3_rthz": non_negative,
            "gyro_bias_walk_rad_s2_rthz": non_negative, "accel_bias_initial_m_s2": non_negative,
            "gyro_bias_initial_rad_s": non_negative},
    "baro": {"rate_hz": _RATE, "noise_m": non_negative, "drift_m_rthz": non_negative},
    "gnss": {"rate_hz": _SCAN_RATE, "pseudorange_sigma_m": non_negative, "correlation_time_s": _CORRELATION,
             "velocity_sigma_m_s": non_negative, "satellites": _integer(0, MAX_SATELLITES),
             "elevation_mask_deg": _in(0.0, 89.0, "deg"), "urban_canyon": boolean,
             "nlos_probability": _PROBABILITY, "outage_rate_per_min": _in(0.0, 60.0, "per minute"),
             "max_outage_s": _in(0.0, MAX_OUTAGE_S, "s"),
             "min_satellites": _integer(MIN_FIX_SATELLITES, MAX_SATELLITES)},
    "heading": {"rate_hz": _RATE, "noise_rad": _ANGLE_SIGMA, "disturbance_rad": _ANGLE_SIGMA,
                "correlation_time_s": _CORRELATION},
    "lidar": {"channels": _integer(1, MAX_LIDAR_RAYS_PER_SCAN), "vertical_fov_deg": _fov,
              "horizontal_resolution_deg": _in(0.0, 360.0, "deg", open_low=True), "rate_hz": _SCAN_RATE,
              "max_range_m": _in(0.0, MAX_RANGE_M, "m", open_low=True), "min_range_m": _in(0.0, MAX_RANGE_M, "m"),
              "range_noise_m": non_negative, "range_noise_per_m": non_negative, "dropout": _PROBABILITY},
}
_KEYS = ("preset", "latency_s", *_FIELDS)


def sensing_from_config(value: Any, mass_kg: float, source: str, key: str = "sensing") -> SensingConfig:
    """The scenario key `sensing:` for a vehicle of `mass_kg` [kg] (which picks its parts: `sensing_preset`).

    Args:
        value: a level name ("perfect", "nominal", "degraded") or a mapping `{preset: <level>, latency_s: s,
            imu: {...}, baro: {...}, gnss: {...}, heading: {...}, lidar: {...}}` of the fields to change.
        mass_kg: the vehicle's mass [kg].
        source: the file, for error messages.
        key: the key's dotted name in the file.

    Returns:
        The level with the changes; `overridden` lists the dotted keys (below `key`) whose value differs from the
        preset's, in the order of `_KEYS` and the spec's fields.

    Raises:
        ConfigError: naming the file, the dotted key and the value: an unknown preset or key, a value of the wrong
            type or out of its range, overrides of `perfect` (it simulates nothing they could change), a lidar with
            more than `MAX_LIDAR_RAYS_PER_SCAN` rays per scan or a minimum range not below its maximum.
    """
    if isinstance(value, str):
        return _preset(value, mass_kg, source, key)
    cfg = mapping(value, source, key, _KEYS,
                  expected=f"a preset ({', '.join(LEVELS)}) or a mapping with keys from {', '.join(_KEYS)}")
    level = cfg.get("preset", DEFAULT_OVERRIDE_PRESET)
    base = _preset(level, mass_kg, source, f"{key}.preset")
    changes: dict[str, Any] = {}
    overridden: list[str] = []
    if "latency_s" in cfg:
        changes["latency_s"] = number_in_range(cfg["latency_s"], (0.0, MAX_LATENCY_S), "s", source,
                                               f"{key}.latency_s")
        if changes["latency_s"] != base.latency_s:
            overridden.append("latency_s")
    for section, checks in _FIELDS.items():
        if section not in cfg:
            continue
        spec = getattr(base, section)
        fields = mapping(cfg[section], source, f"{key}.{section}", tuple(checks),
                         expected=f"a mapping with keys from {', '.join(checks)}")
        parsed = {name: checks[name](v, source, f"{key}.{section}.{name}") for name, v in fields.items()}
        changes[section] = dataclasses.replace(spec, **parsed)
        overridden += [f"{section}.{name}" for name in checks if name in parsed and parsed[name] != getattr(spec, name)]
    if base.perfect and cfg.keys() - {"preset"}:
        raise ConfigError(source, key, f"overrides of the perfect level ({', '.join(k for k in cfg if k != 'preset')})"
                                       f": it simulates no sensor; start from preset nominal or degraded")
    if "lidar" in changes:
        _check_lidar(changes["lidar"], cfg["lidar"], source, f"{key}.lidar")
    return dataclasses.replace(base, **changes, overridden=tuple(overridden))


def _preset(level: Any, mass_kg: float, source: str, key: str) -> SensingConfig:
    if not isinstance(level, str) or level not in LEVELS:
        raise ConfigError(source, key, f"unknown sensing preset {level!r} (presets: {', '.join(LEVELS)})")
    return sensing_preset(level, mass_kg)


def _check_lidar(spec: Any, given: Mapping, source: str, key: str) -> None:
    """The lidar's checks across fields: rays per scan (from channels and resolution, as floats: nothing is
    allocated or rounded to a huge integer) and min range below max range."""
    rays = spec.channels * (360.0 / spec.horizontal_resolution_deg)
    if rays > MAX_LIDAR_RAYS_PER_SCAN:
        name = "channels" if "channels" in given else "horizontal_resolution_deg"
        raise ConfigError(source, f"{key}.{name}",
                          f"{spec.channels} channels x {360.0 / spec.horizontal_resolution_deg:.6g} columns "
                          f"(horizontal_resolution_deg {spec.horizontal_resolution_deg:g}) = {rays:.4g} rays per "
                          f"scan; at most {MAX_LIDAR_RAYS_PER_SCAN:,}")
    if spec.channels > 1 and not spec.vertical_fov_deg[1] > spec.vertical_fov_deg[0]:
        raise ConfigError(source, f"{key}.vertical_fov_deg", f"must span an angle for {spec.channels} channels, "
                                                             f"got {list(spec.vertical_fov_deg)}")
    if not spec.min_range_m < spec.max_range_m:
        name = "min_range_m" if "min_range_m" in given else "max_range_m"
        raise ConfigError(source, f"{key}.{name}", f"min_range_m {spec.min_range_m:g} m must be below max_range_m "
                                                   f"{spec.max_range_m:g} m")
