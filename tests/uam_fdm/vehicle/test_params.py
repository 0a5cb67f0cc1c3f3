"""Vehicle parameter files: presets load, bad values are rejected naming file, key and reason."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from uam_fdm.errors import ConfigError
from uam_fdm.vehicle.params import PRESET_DIR, load_vehicle, preset_names


def test_presets_are_shipped_and_plausible():
    assert {"small_quad", "uam_multicopter"} <= set(preset_names())
    quad, uam = load_vehicle("small_quad"), load_vehicle("uam_multicopter")
    assert 1.0 <= quad.mass_kg <= 3.0 and quad.n_rotors == 4
    assert 100.0 <= uam.mass_kg <= 1000.0 and uam.n_rotors >= 8
    for p in (quad, uam):
        tw = p.max_thrust_N() / p.weight_N
        assert 1.4 <= tw <= 3.0, f"{p.name}: thrust/weight {tw:.2f}"
        # Momentum theory (textbook): real hovering rotors reach a figure of merit of about 0.4-0.75.
        assert 0.35 <= p.hover_figure_of_merit() <= 0.8, f"{p.name}: figure of merit {p.hover_figure_of_merit():.2f}"
        hover = p.hover_rotor_speeds_rad_s()
        assert np.ptp(hover) < 1e-9 * hover.mean()   # symmetric presets: equal trim speeds
        reach = np.linalg.norm(p.rotor_positions[:, :2], axis=1).max()
        assert p.collision_radius_m > reach   # the sphere encloses every rotor hub
    # Loading by path gives the same parameters as loading by name.
    assert load_vehicle(PRESET_DIR / "small_quad.yaml") == quad


def _write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "vehicle.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture()
def quad_dict() -> dict:
    return yaml.safe_load((PRESET_DIR / "small_quad.yaml").read_text())


def _mutated(d: dict, key_path: tuple, value) -> dict:
    d = copy.deepcopy(d)
    target = d
    for k in key_path[:-1]:
        target = target[k]
    target[key_path[-1]] = value
    return d


@pytest.mark.parametrize("key_path, value, key, reason", [
    (("mass_kg",), 0.0, "mass_kg", "must be positive"),
    (("mass_kg",), -1.5, "mass_kg", "must be positive"),
    (("mass_kg",), "heavy", "mass_kg", "must be a number"),
    (("mass_kg",), float("nan"), "mass_kg", "must be finite"),
    (("inertia_kg_m2",), [[0.03, 0, 0], [0, -0.03, 0], [0, 0, 0.05]], "inertia_kg_m2", "positive definite"),
    (("inertia_kg_m2",), [[0.03, 0.01, 0], [0, 0.03, 0], [0, 0, 0.05]], "inertia_kg_m2", "symmetric"),
    (("inertia_kg_m2",), [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.05]], "inertia_kg_m2", "triangle inequality"),
    (("inertia_kg_m2",), [[0.03, 0, 0], [0, 0.03, 0]], "inertia_kg_m2", "3x3"),
    (("rotor_speed_max_rad_s",), 300.0, "rotor_speed_max_rad_s", "below the weight"),
    (("rotor_speed_min_rad_s",), 2000.0, "rotor_speed_min_rad_s", "must be below rotor_speed_max_rad_s"),
    (("thrust_coeff_N_s2",), 0, "thrust_coeff_N_s2", "must be positive"),
    (("rotors", 0, "spin"), "sideways", "rotors[0].spin", "'ccw' or 'cw'"),
    (("rotors", 1, "spin"), "cw", "rotors", "spins must balance"),
    (("rotors", 2, "position_m"), [0.1, 0.2], "rotors[2].position_m", "list of 3 numbers"),
    (("drag_linear_N_s_m",), [0.1, -0.1, 0.1], "drag_linear_N_s_m", ">= 0.0"),
    (("controller", "max_tilt_deg"), 85.0, "controller.max_tilt_deg", "(0, 80)"),
    (("controller", "max_speed_m_s"), -3.0, "controller.max_speed_m_s", "must be positive"),
])
def test_bad_values_name_file_key_and_reason(tmp_path, quad_dict, key_path, value, key, reason):
    path = _write(tmp_path, _mutated(quad_dict, key_path, value))
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    err = info.value
    assert err.source == str(path) and err.key == key and reason in err.reason, str(err)
    assert str(path) in str(err) and key in str(err)


def test_unknown_and_missing_keys(tmp_path, quad_dict):
    with pytest.raises(ConfigError, match=r"vehicle.yaml: mass_lb: unknown key"):
        load_vehicle(_write(tmp_path, {**quad_dict, "mass_lb": 3.3}))
    with pytest.raises(ConfigError, match=r"controller.gain: unknown key"):
        load_vehicle(_write(tmp_path, _mutated(quad_dict, ("controller", "gain"), 1.0)))
    with pytest.raises(ConfigError, match=r"rotors\[3\].diameter_m: unknown key"):
        load_vehicle(_write(tmp_path, _mutated(quad_dict, ("rotors", 3, "diameter_m"), 0.25)))
    missing = dict(quad_dict)
    del missing["motor_time_constant_s"]
    with pytest.raises(ConfigError, match=r"motor_time_constant_s: missing"):
        load_vehicle(_write(tmp_path, missing))


def test_geometry_without_yaw_authority_is_rejected(tmp_path, quad_dict):
    # All rotors on one line: roll authority only along that line.
    rotors = [{"position_m": [0.1 * i - 0.15, 0.0, 0.0], "spin": s} for i, s in enumerate(["ccw", "cw", "ccw", "cw"])]
    with pytest.raises(ConfigError, match="rotors: geometry cannot set thrust, roll, pitch and yaw"):
        load_vehicle(_write(tmp_path, {**quad_dict, "rotors": rotors}))


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not a preset"):
        load_vehicle(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("mass_kg: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_vehicle(bad)
