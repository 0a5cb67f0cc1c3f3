"""Ground effect: the model's thrust gain against Cheeseman-Bennett at several heights,
in hover and forward flight; the switch; the surface below a point; the one rule for the height input."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap, Prism
from uam_fdm.errors import ConfigError
from uam_fdm.vehicle import ground_effect as ge
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.model import hover_state, make_env
from uam_fdm.vehicle.params import GRAVITY_M_S2, PRESET_DIR, load_vehicle

HEIGHTS_OVER_R = (0.6, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0)


def test_gain_follows_cheeseman_bennett_within_its_cutoff_offset() -> None:
    zr = np.array(HEIGHTS_OVER_R)
    for v_ratio in (0.0, 0.5, 2.0):
        ours, law = ge.thrust_gain(zr, v_ratio), ge.cheeseman_bennett(zr, v_ratio)
        # the only departure is the subtracted (1/40)^2 that makes the gain exactly 1 at 10 R
        assert np.all(np.abs(ours - law) <= (0.25 / ge.CUTOFF_RADII) ** 2 * law ** 2 + 1e-15)
        assert np.all(np.diff(ours) < 0)  # closer is stronger
    assert ge.cheeseman_bennett(1.0) == pytest.approx(1.0 / (1.0 - 1.0 / 16.0))  # 1.0667 at one radius
    k = lambda g: 1.0 - 1.0 / float(g)  # noqa: E731  (G = 1 / (1 - k))
    assert k(ge.thrust_gain(2.0, 2.0)) == pytest.approx(k(ge.thrust_gain(2.0)) / 5.0, rel=1e-12)  # V = 2 v_h: k / 5
    assert np.all(ge.thrust_gain([ge.CUTOFF_RADII, 12.0, 1e6]) == 1.0)  # exactly, beyond the cut-off
    assert ge.thrust_gain(0.1) == ge.thrust_gain(ge.MIN_HEIGHT_RADII) == pytest.approx(1.0 / (1.0 - 0.25 + 0.000625))


@pytest.mark.parametrize("height_over_r", HEIGHTS_OVER_R)
def test_model_hover_thrust_gain_at_height(height_over_r: float) -> None:
    """Level hover with every hub at z = height_over_r * R: the model's vertical acceleration is (G - 1) g."""
    p = load_vehicle("small_quad")
    dyn = VehicleDynamics(p, 500.0, 50.0, compiled=False)
    radius = 0.5 * p.rotor_diameter_m
    hub_dz = p.rotor_positions[0, 2]  # 2.3 cm above the centre of mass, level
    x = hover_state(p, (0.0, 0.0, 10.0))
    acc = dyn.x_dot(x, x[13:], make_env(height_above_surface_m=height_over_r * radius - hub_dz))[5]
    assert acc == pytest.approx((float(ge.thrust_gain(height_over_r)) - 1.0) * GRAVITY_M_S2, rel=1e-9, abs=1e-12)


def test_forward_flight_weakens_it_and_the_switch_removes_it() -> None:
    p = load_vehicle("small_quad")
    radius = 0.5 * p.rotor_diameter_m
    x = hover_state(p, (0.0, 0.0, 10.0))
    env = make_env(height_above_surface_m=1.0 * radius - p.rotor_positions[0, 2])
    hover = VehicleDynamics(p, 500.0, 50.0, compiled=False).x_dot(x, x[13:], env)[5]
    # V / v_h = 1 in the rotor plane: k halves
    v_h = float(x[13]) * math.sqrt(p.thrust_coeff_N_s2 / (2.0 * ge.RHO0_KG_M3 * math.pi * radius ** 2))
    moving = x.copy()
    moving[3] = v_h
    dyn = VehicleDynamics(dataclasses.replace(p, drag_linear_N_s_m=(0, 0, 0), drag_quadratic_N_s2_m2=(0, 0, 0)),
                          500.0, 50.0, compiled=False)
    fwd = dyn.x_dot(moving, x[13:], env)[5]
    assert fwd == pytest.approx((float(ge.thrust_gain(1.0, 1.0)) - 1.0) * GRAVITY_M_S2, rel=1e-6)
    assert 0 < fwd < hover
    off = VehicleDynamics(dataclasses.replace(p, ground_effect=False), 500.0, 50.0, compiled=False)
    assert off.x_dot(x, x[13:], env)[5] == pytest.approx(0.0, abs=1e-12)


def test_vehicle_yaml_switch(tmp_path) -> None:
    text = (PRESET_DIR / "small_quad.yaml").read_text()
    (tmp_path / "off.yaml").write_text(text + "\nground_effect: false\n")
    assert load_vehicle("small_quad").ground_effect and not load_vehicle(tmp_path / "off.yaml").ground_effect
    (tmp_path / "bad.yaml").write_text(text + "\nground_effect: 1\n")
    with pytest.raises(ConfigError, match="ground_effect: must be true or false, got 1"):
        load_vehicle(tmp_path / "bad.yaml")


def _city() -> BuildingMap:
    return BuildingMap(
        [Building(0, (20.0, 20.0), (10.0, 6.0), 12.0, yaw_rad=math.radians(30.0)),
         Building(1, (20.0, 20.0), (2.0, 2.0), 15.0),  # a roof box on top: the higher roof wins where both are below
         Prism(2, ((50.0, 10.0), (60.0, 10.0), (55.0, 20.0)), 8.0)],
        (0.0, 0.0, 0.0), (80.0, 40.0, 60.0))


def test_surface_below_a_point() -> None:
    city = _city()
    c30, s30 = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    pts = np.array([[5.0, 5.0, 3.0],                                   # open ground
                    [20.0, 20.0, 20.0],                                # above both roofs: the higher
                    [20.0, 20.0, 13.0],                                # between them: the lower roof
                    [20.0 + 4.99 * c30, 20.0 + 4.99 * s30, 12.5],      # inside the yawed footprint, near its end
                    [20.0 + 5.01 * c30, 20.0 + 5.01 * s30, 12.5],      # just outside it
                    [55.0, 12.0, 9.0], [55.0, 21.0, 9.0]])             # the triangle, then above its apex
    np.testing.assert_array_equal(city.surface_height_m(pts), [0.0, 15.0, 12.0, 12.0, 0.0, 8.0, 0.0])


def test_the_height_rule_looks_up_only_near_surfaces() -> None:
    p = load_vehicle("small_quad")
    city = _city()
    reach = ge.range_m(p)
    assert reach == pytest.approx(10 * 0.127 + float(np.max(np.linalg.norm(p.rotor_positions, axis=1))))
    pos = np.array([[20.0, 20.0, 16.0], [20.0, 20.0, 16.0], [5.0, 5.0, 1.0]])
    clearance = np.array([0.5, reach + 1.0, 1.0 - p.collision_radius_m])
    h = ge.height_above_surface(city, pos, clearance, p)
    np.testing.assert_allclose(h, [1.0, 16.0, 1.0])  # near: above the roof; far: its altitude (no lookup)
    off = dataclasses.replace(p, ground_effect=False)
    np.testing.assert_array_equal(ge.height_above_surface(city, pos, clearance, off), pos[:, 2])
    np.testing.assert_array_equal(ge.height_above_surface(None, pos, clearance, p), pos[:, 2])
