"""The potential-field pilot as a `Pilot`: the runner flies it exactly as the evaluation environment
flies `rl.pilots.potential_field.BatchedPotentialField` (same sensing, same command path, same low-level controller)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from compare.flying.episode_loop import run_episode
from rl.env.gym_env import UAMNavEnv
from rl.env.world import NavWorld
from rl.pilots.potential_field import BatchedPotentialField, PotentialFieldConfig, PotentialFieldPilot, gains_for
from rl.task.config import NavConfig
from rl.training.evaluation import eval_config
from uam_fdm.pilot import Pilot, World
from uam_fdm.vehicle.params import load_vehicle


@pytest.mark.parametrize("seed", [3])
def test_apf_pilot_flies_exactly_like_the_evaluation_environment(seed):
    """One held-out episode (light turbulence), the field deciding every control period as in
    `rl.training.evaluation.evaluate_potential_field`: the same states at every decision, the same outcome."""
    nav = NavConfig()
    base = NavWorld(replace(eval_config(nav, 3), decision_hz=nav.control_hz))
    env = UAMNavEnv(world=base)
    obs, _ = env.reset(seed=seed)
    field = BatchedPotentialField(env.batch, gains_for(base.vehicle))  # the gains the pilot flies (tuned)
    task, wind, city = env.batch.task(0), env.batch.wind_field(0), base.cities[int(env.batch.city[0])]
    env_states, outcome = [], None
    for _ in range(100_000):
        obs, _, term, trunc, info = env.step(field(obs[None], env.batch)[0])
        env_states.append(env.state)
        if term or trunc:
            outcome = info["outcome"]
            break
    pilot = PotentialFieldPilot()
    assert isinstance(pilot, Pilot) and pilot.name == "apf"
    traj = run_episode(World(base.vehicle, base.dynamics, city, base.atmosphere), pilot, task, wind, seed=0)
    per_decision = base.dynamics.n_substeps
    assert traj.outcome == outcome and pilot.episode_report() is None
    assert len(traj.decision_t_s) == len(env_states)
    np.testing.assert_array_equal(traj.states[per_decision::per_decision], np.array(env_states))
    assert traj.plan_time_s == 0.0


def test_gains_scale_with_the_vehicles_task():
    """Untuned, a vehicle's gains are the small quad's scaled to its task (x4 for the UAM); the shipped table's
    gains, tuned per vehicle on validation legs (perf/apf_gains.py), take their place."""
    from rl.pilots.potential_field import gains_for_task, tuned_gains
    from rl.task.vehicles import task_for

    assert gains_for_task(task_for("small_quad").scales) == PotentialFieldConfig()
    uam = gains_for_task(task_for("uam_multicopter").scales)
    assert uam.range_m == 4 * PotentialFieldConfig().range_m and uam.k_buildings == PotentialFieldConfig().k_buildings
    for vehicle in ("small_quad", "uam_multicopter"):
        assert gains_for(load_vehicle(vehicle)) == tuned_gains()[vehicle]


def test_gains_tuned_per_vehicle_are_read_from_their_table(tmp_path):
    """A vehicle with tuned gains flies them (read with every key checked); the others the small quad's gains
    scaled to their task; a table with a missing or unknown gain is refused, naming the file and vehicle."""
    from dataclasses import asdict

    from rl.pilots.potential_field import TUNED, gains_for, gains_for_task, tuned_gains
    from rl.task.vehicles import task_for
    from uam_fdm.vehicle.params import load_vehicle

    tuned = replace(TUNED, repulsion=3.0, range_m=77.0)
    path = tmp_path / "gains.json"
    path.write_text(json.dumps({"vehicles": {"uam_multicopter": {"gains": asdict(tuned), "provenance": {}}}}))
    assert tuned_gains(path) == {"uam_multicopter": tuned}
    assert tuned_gains(tmp_path / "none.json") == {}
    bad = dict(asdict(tuned), wings=1)
    path.write_text(json.dumps({"vehicles": {"uam_multicopter": {"gains": bad}}}))
    tuned_gains.cache_clear()
    with pytest.raises(ValueError, match=r"gains.json: vehicles.uam_multicopter.gains must hold exactly"):
        tuned_gains(path)
    tuned_gains.cache_clear()
    quad = load_vehicle("small_quad")
    assert gains_for(quad) == tuned_gains().get("small_quad", gains_for_task(task_for("small_quad").scales))


def test_apf_on_its_sensors_and_a_wrong_map_flies_as_the_runner_flies_it():
    """Below perfect sensing over a wrong map the batched field knows what the runner's pilot is given: its estimate
    and the prior map (not the truth it collides with); the same true states at every decision, the same outcome."""
    from rl.env.world import NavBatch
    from uam_fdm.pilot import Truth
    from uam_fdm.sensing.specs import sensing_preset

    nav = replace(eval_config(NavConfig(), 3), sensing=("nominal",), map_error=("wrong",), map_error_draws=1)
    base = NavWorld(replace(nav, decision_hz=nav.control_hz))
    batch = NavBatch(base, 1)
    batch.seed([3])
    batch.reset_slots([0])
    ci = int(batch.city[0])
    draw = base.maps.draw(ci, int(batch.map_level[0]), int(batch.map_draw[0]))
    assert draw.prior is not draw.truth and batch.priors[0] is draw.prior
    task, wind, seed = batch.task(0), batch.wind_field(0), int(batch.sensing_seed[0])
    field = BatchedPotentialField(batch, gains_for(base.vehicle))
    obs, states, outcome = batch.observations.copy(), [], None
    for _ in range(100_000):
        obs, _, term, trunc, info = batch.step(field(obs, batch))
        assert not np.array_equal(batch.x_seen[0, 0:3], batch.x[0, 0:3])  # it decides on the estimate
        states.append(batch.x[0].copy())
        if term[0] or trunc[0]:
            outcome = info[0]["outcome"]
            break
    sensing = sensing_preset("nominal", base.vehicle.mass_kg)
    given = World(base.vehicle, base.dynamics, draw.prior, batch.atmosphere(0), batch.turbulence(0), sensing=sensing)
    traj = run_episode(given, PotentialFieldPilot(), task, wind, 0, truth=Truth(draw.truth, sensing, seed))
    per_decision = base.dynamics.n_substeps
    assert len(states) > 30 and traj.outcome == outcome
    # bit for bit on the Intel machines this ran on before; on an AMD EPYC (AVX2, no AVX-512) the two paths differ in
    # the last bits (7e-12 at most over this flight; likely numpy's SIMD loops by array shape)
    np.testing.assert_allclose(traj.states[per_decision::per_decision], np.array(states), rtol=1e-9, atol=1e-9)


def test_a_batch_mixing_exact_and_drawn_priors_senses_each_slots_own():
    """Slots on their city and slots on a drawn prior in one batch: each row is what the slot's own map gives."""
    from rl.env.world import NavBatch
    from rl.sensing.observation import world_velocity_to_action
    from rl.sensing.sensor import BoxSensor

    nav = replace(eval_config(NavConfig(), 6), map_error=("exact", "wrong"), map_error_draws=1)
    base = NavWorld(replace(nav, decision_hz=nav.control_hz))
    batch = NavBatch(base, 6)
    batch.seed(range(10, 16))
    batch.reset_slots(range(6))
    drawn = [batch.priors[i] is not base.cities[int(batch.city[i])] for i in range(6)]
    assert any(drawn) and not all(drawn)
    gains = gains_for(base.vehicle)
    got = BatchedPotentialField(batch, gains)(batch.observations.copy(), batch)
    radius = base.vehicle.collision_radius_m
    for i in range(6):
        sensor = BoxSensor([batch.priors[i]], gains.k_buildings, gains.range_m, radius)
        p = batch.x_seen[i:i + 1, 0:3]
        r = sensor.query(p, np.zeros(1, dtype=np.int64))
        v = gains.velocity(p, batch.goal[i:i + 1], r.nearest_m, r.distance_m)
        np.testing.assert_allclose(got[i], world_velocity_to_action(v, batch.memory.heading_rad[i:i + 1])[0],
                                   rtol=0, atol=1e-12)
