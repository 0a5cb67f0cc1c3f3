"""Vehicle parameters: a frozen dataclass and its strict YAML loader.

Body frame FLU (x forward, y left, z up) with the origin at the centre of mass; SI units.
Rotor i at body position r_i gives thrust kf·σ·Ω_i² along +z_body and a reaction torque
−s_i·km·σ·Ω_i² about z_body (s_i = +1 for a rotor spinning counter-clockwise seen from above),
σ = ρ/ρ0 being the air-density ratio.
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import (
    boolean,
    mapping,
    non_negative,
    number,
    number_list,
    positive,
    reject_unknown,
    require_keys,
    root_mapping,
    string,
)
from uam_fdm.files.yamlfile import load_yaml_file

GRAVITY_M_S2 = 9.80665
PRESET_DIR = Path(__file__).parent / "presets"
# controller.max_speed_m_s [m/s]: the default episode timeout divides by it (a tiny value gives a
# timeout of days) and the wind model's airspeed is capped at 100 m/s; multicopters fly below it.
MAX_SPEED_RANGE_M_S = (0.5, 100.0)


@dataclass(frozen=True)
class ControllerConfig:
    """Limits and gains of the low-level velocity controller (see `uam_fdm.vehicle.control`).

    Gains are normalised by mass and inertia, so they read as bandwidths:
    velocity loop a = K_v·(v_cmd − v) + K_i·∫(v_cmd − v) [m/s²]; attitude loop
    α = −ω_n²·e_R − 2ζω_n·ω [rad/s²].
    """

    max_speed_m_s: float
    max_vertical_speed_m_s: float
    max_tilt_deg: float
    velocity_gain_1_s: float = 2.5
    velocity_integral_gain_1_s2: float = 1.2
    integral_limit_m_s2: float = 3.0
    integral_window_m_s: float = 0.5
    attitude_natural_freq_rad_s: float = 14.0
    attitude_damping: float = 0.8
    yaw_natural_freq_rad_s: float = 3.0
    max_yaw_rate_rad_s: float = 1.5


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of one multirotor (SI units, body FLU about the centre of mass)."""

    name: str
    description: str
    mass_kg: float
    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    rotor_positions_m: tuple[tuple[float, float, float], ...]
    rotor_spins: tuple[int, ...]
    rotor_diameter_m: float
    thrust_coeff_N_s2: float
    torque_coeff_Nm_s2: float
    motor_time_constant_s: float
    rotor_speed_min_rad_s: float
    rotor_speed_max_rad_s: float
    drag_linear_N_s_m: tuple[float, float, float]
    drag_quadratic_N_s2_m2: tuple[float, float, float]
    collision_radius_m: float
    controller: ControllerConfig
    ground_effect: bool = True  # the rotors' thrust gain near a surface below (`uam_fdm.vehicle.ground_effect`)
    source: str = field(default="<inline>", compare=False)

    @property
    def n_rotors(self) -> int:
        return len(self.rotor_spins)

    @property
    def inertia(self) -> np.ndarray:
        """Inertia tensor (3, 3) [kg·m²], body FLU."""
        return np.array(self.inertia_kg_m2, dtype=float)

    @property
    def rotor_positions(self) -> np.ndarray:
        """Rotor hub positions (n, 3) [m], body FLU."""
        return np.array(self.rotor_positions_m, dtype=float)

    @property
    def weight_N(self) -> float:
        return self.mass_kg * GRAVITY_M_S2

    def max_thrust_N(self, density_ratio: float = 1.0) -> float:
        """Total thrust with every rotor at its maximum speed [N]."""
        return self.n_rotors * self.thrust_coeff_N_s2 * density_ratio * self.rotor_speed_max_rad_s**2

    def hover_figure_of_merit(self) -> float:
        """Momentum-theory ideal hover power T^1.5/sqrt(2 ρ0 A) over the model's shaft power Σ km Ω³."""
        disk_area = self.n_rotors * math.pi * self.rotor_diameter_m**2 / 4
        ideal = self.weight_N**1.5 / math.sqrt(2 * 1.225 * disk_area)
        shaft = float(np.sum(self.torque_coeff_Nm_s2 * self.hover_rotor_speeds_rad_s() ** 3))
        return ideal / shaft

    def allocation_matrix(self, density_ratio: float = 1.0) -> np.ndarray:
        """Matrix A (4, n) with [T, Mx, My, Mz] = A @ Ω² (N, N·m; body FLU)."""
        kf = self.thrust_coeff_N_s2 * density_ratio
        km = self.torque_coeff_Nm_s2 * density_ratio
        r = self.rotor_positions
        s = np.array(self.rotor_spins, dtype=float)
        return np.vstack([np.full(self.n_rotors, kf), kf * r[:, 1], -kf * r[:, 0], -km * s])

    def hover_rotor_speeds_rad_s(self, density_ratio: float = 1.0) -> np.ndarray:
        """Rotor speeds (n,) [rad/s] that give thrust = weight and zero torque (least-squares allocation)."""
        wrench = np.array([self.weight_N, 0.0, 0.0, 0.0])
        omega_sq = np.linalg.pinv(self.allocation_matrix(density_ratio)) @ wrench
        return np.sqrt(np.maximum(omega_sq, 0.0))

    def fingerprint(self) -> str:
        """Stable hash of every physical value (not the name or source); keys compiled-code caches."""
        values = dataclasses.asdict(self)
        for key in ("name", "description", "source"):
            values.pop(key)
        return hashlib.sha256(repr(sorted(values.items())).encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------

_TOP_KEYS = {
    "name", "description", "mass_kg", "inertia_kg_m2", "rotors", "rotor_diameter_m", "thrust_coeff_N_s2",
    "torque_coeff_Nm_s2",
    "motor_time_constant_s", "rotor_speed_min_rad_s", "rotor_speed_max_rad_s", "drag_linear_N_s_m",
    "drag_quadratic_N_s2_m2", "collision_radius_m", "controller", "ground_effect",
}
_OPTIONAL_TOP_KEYS = {"description", "ground_effect"}
_ROTOR_KEYS = {"position_m", "spin"}
_SPINS = {"ccw": 1, "cw": -1}


MAX_VEHICLE_NAME_CHARS = 100
"""Longest vehicle name: it heads the report's pages, the summary's blocks and the viewer's read-outs."""


def _vehicle_name(value: Any, source: str) -> str:
    name = string(value, source, "name")
    if not name.strip() or len(name) > MAX_VEHICLE_NAME_CHARS or not name.isprintable():
        raise ConfigError(source, "name", f"must be 1 to {MAX_VEHICLE_NAME_CHARS} printable characters, got "
                                          f"{len(name)}: {name[:20]!r}" + ("..." if len(name) > 20 else ""))
    return name


def preset_names() -> list[str]:
    """Names of the shipped vehicle presets."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def load_vehicle(name_or_path: str | Path) -> VehicleParams:
    """Load a shipped preset by name (e.g. ``"small_quad"``) or a vehicle YAML file by path.

    Raises:
        ConfigError: naming the file, the key and the reason for any bad value.
    """
    path = Path(name_or_path)
    if not path.suffix and (PRESET_DIR / f"{name_or_path}.yaml").exists():
        path = PRESET_DIR / f"{name_or_path}.yaml"
    if not path.exists():
        raise ConfigError(str(name_or_path), "vehicle",
                          f"no such file and not a preset (presets: {', '.join(preset_names())})")
    if not path.is_file():
        raise ConfigError(str(path), "vehicle", "is a folder, not a vehicle YAML file")
    data = load_yaml_file(path)  # strict: duplicate keys, bounded aliases, UTF-8 text
    return vehicle_from_dict(data, source=str(path))


def vehicle_from_dict(data: Any, source: str = "<inline>") -> VehicleParams:
    """Build and validate `VehicleParams` from a parsed mapping (e.g. a scenario's `vehicle` block)."""
    root_mapping(data, source, "vehicle parameters")
    reject_unknown(data, _TOP_KEYS, source)
    require_keys(data, sorted(_TOP_KEYS - _OPTIONAL_TOP_KEYS), source)

    rotors = data["rotors"]
    if not isinstance(rotors, list) or len(rotors) < 4:
        raise ConfigError(source, "rotors", "must be a list of at least 4 rotors")
    positions, spins = [], []
    for i, rotor in enumerate(rotors):
        key = f"rotors[{i}]"
        mapping(rotor, source, key, _ROTOR_KEYS, expected="a mapping with position_m and spin")
        positions.append(_vector(rotor.get("position_m"), 3, source, key + ".position_m"))
        spin = rotor.get("spin")
        if spin not in _SPINS:
            raise ConfigError(source, key + ".spin", f"must be 'ccw' or 'cw', got {spin!r}")
        spins.append(_SPINS[spin])

    params = VehicleParams(
        name=_vehicle_name(data["name"], source),
        description=string(data.get("description", ""), source, "description"),
        mass_kg=positive(data["mass_kg"], source, "mass_kg"),
        inertia_kg_m2=_matrix3(data["inertia_kg_m2"], source, "inertia_kg_m2"),
        rotor_positions_m=tuple(positions),
        rotor_spins=tuple(spins),
        rotor_diameter_m=positive(data["rotor_diameter_m"], source, "rotor_diameter_m"),
        thrust_coeff_N_s2=positive(data["thrust_coeff_N_s2"], source, "thrust_coeff_N_s2"),
        torque_coeff_Nm_s2=positive(data["torque_coeff_Nm_s2"], source, "torque_coeff_Nm_s2"),
        motor_time_constant_s=positive(data["motor_time_constant_s"], source, "motor_time_constant_s"),
        rotor_speed_min_rad_s=non_negative(data["rotor_speed_min_rad_s"], source, "rotor_speed_min_rad_s"),
        rotor_speed_max_rad_s=positive(data["rotor_speed_max_rad_s"], source, "rotor_speed_max_rad_s"),
        drag_linear_N_s_m=_vector(data["drag_linear_N_s_m"], 3, source, "drag_linear_N_s_m", min_value=0.0),
        drag_quadratic_N_s2_m2=_vector(data["drag_quadratic_N_s2_m2"], 3, source, "drag_quadratic_N_s2_m2",
                                       min_value=0.0),
        collision_radius_m=positive(data["collision_radius_m"], source, "collision_radius_m"),
        controller=_controller(data["controller"], source),
        ground_effect=boolean(data.get("ground_effect", True), source, "ground_effect"),
        source=source,
    )
    check_physics(params, source)
    return params


def check_physics(p: VehicleParams, source: str = "<inline>") -> None:
    """Reject parameter sets that cannot describe a flyable multirotor (raises ConfigError)."""
    inertia = p.inertia
    if not np.allclose(inertia, inertia.T, rtol=1e-9, atol=1e-12):
        raise ConfigError(source, "inertia_kg_m2", "must be symmetric")
    eig = np.linalg.eigvalsh(inertia)
    if eig.min() <= 0.0:
        raise ConfigError(source, "inertia_kg_m2", f"must be positive definite (eigenvalues {eig.tolist()})")
    if eig.max() > eig.sum() - eig.max() + 1e-12:
        raise ConfigError(source, "inertia_kg_m2",
                          f"principal moments {eig.tolist()} violate the triangle inequality (no real body has them)")
    if p.rotor_speed_min_rad_s >= p.rotor_speed_max_rad_s:
        raise ConfigError(source, "rotor_speed_min_rad_s",
                          f"{p.rotor_speed_min_rad_s} must be below rotor_speed_max_rad_s {p.rotor_speed_max_rad_s}")
    if p.max_thrust_N() <= p.weight_N:
        raise ConfigError(source, "rotor_speed_max_rad_s",
                          f"max thrust {p.max_thrust_N():.1f} N is below the weight {p.weight_N:.1f} N")
    if sum(p.rotor_spins) != 0:
        raise ConfigError(source, "rotors", f"spins must balance (as many ccw as cw), sum is {sum(p.rotor_spins)}")
    if np.linalg.matrix_rank(p.allocation_matrix()) < 4:
        raise ConfigError(source, "rotors", "geometry cannot set thrust, roll, pitch and yaw independently")
    hover = p.hover_rotor_speeds_rad_s()
    if hover.max() >= p.rotor_speed_max_rad_s or hover.min() <= p.rotor_speed_min_rad_s:
        raise ConfigError(source, "rotors",
                          f"hover needs rotor speeds {hover.min():.0f}..{hover.max():.0f} rad/s, outside the limits")


def _controller(data: Any, source: str) -> ControllerConfig:
    mapping(data, source, "controller", {f.name for f in dataclasses.fields(ControllerConfig)})
    values = {k: positive(v, source, f"controller.{k}") for k, v in data.items()}
    try:
        ctrl = ControllerConfig(**values)
    except TypeError:
        required = {f.name for f in dataclasses.fields(ControllerConfig) if f.default is dataclasses.MISSING}
        raise ConfigError(source, "controller", f"missing {sorted(required - set(values))}") from None
    if not 0.0 < ctrl.max_tilt_deg < 80.0:
        raise ConfigError(source, "controller.max_tilt_deg", f"must be in (0, 80), got {ctrl.max_tilt_deg}")
    lo, hi = MAX_SPEED_RANGE_M_S
    if not lo <= ctrl.max_speed_m_s <= hi:
        raise ConfigError(source, "controller.max_speed_m_s", f"must be in [{lo:g}, {hi:g}] m/s, "
                                                              f"got {ctrl.max_speed_m_s:g}")
    return ctrl


def _vector(value: Any, n: int, source: str, key: str, min_value: float | None = None) -> tuple:
    """n finite numbers, each named by its index when bad (`drag_linear_N_s_m[1]`)."""
    out = tuple(number(v, source, f"{key}[{i}]") for i, v in enumerate(number_list(value, n, source, key)))
    if min_value is not None and min(out) < min_value:
        raise ConfigError(source, key, f"entries must be >= {min_value}, got {list(out)}")
    return out


def _matrix3(value: Any, source: str, key: str) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ConfigError(source, key, f"must be a 3x3 list of lists, got {value!r}")
    return tuple(_vector(row, 3, source, f"{key}[{i}]") for i, row in enumerate(value))
