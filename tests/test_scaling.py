"""Dynamic scaling (app/sim/scaling.py): the lab-unit ODS is the orbit's, scaled; the
paper's law is unchanged; impulse round-trips; what breaks similarity is refused."""

import numpy as np
import pytest

from app.config import ConfigError, EmulatorConfig, parse_config
from app.scenarios import load_scenario
from app.sim.loop import Emulator
from app.sim.orbital import OrbitalSimulator, box_inertia, orbit_rate
from app.sim.scaling import describe, orbit_equivalent_material, scaling_of, summary_line

K_L, K_T, K_M = 4.0, 50.0, 3.0
SAT = {"name": "big", "mass_kg": 200.0, "inertia_kgm2": [40.0, 55.0, 70.0],
       "mockup_mass_kg": 1.0, "position_m": [2.0, -1.0, 0.5],
       "velocity_mps": [0.01, -0.02, 0.005], "attitude_wxyz": [0.9, 0.1, -0.3, 0.2],
       "omega_radps": [0.002, -0.001, 0.003]}


def _similar(**scaling) -> EmulatorConfig:
    return parse_config({"scaling": {"law": "similarity", **scaling}, "satellites": [SAT]})


def _orbit_units() -> EmulatorConfig:
    """The same satellite in orbit units: the paper's law with unit knobs."""
    return parse_config({"orbit": {"force_scale": 1.0, "torque_scale": 1.0},
                         "satellites": [{k: v for k, v in SAT.items()
                                         if k != "mockup_mass_kg"}]})


def test_the_lab_unit_ods_is_the_orbit_s_scaled_step_by_step():
    """x = k_L x', t = k_T t' (module doc): RK4 in lab units under a lab wrench gives, step
    by step, RK4 in orbit units under the orbit wrench k_M k_L / k_T² F, k_M k_L² / k_T² τ,
    with gravity gradient and the CW terms."""
    lab = OrbitalSimulator.from_config(_similar(length=K_L, time=K_T, mass=K_M))
    orbit = OrbitalSimulator.from_config(_orbit_units())
    assert lab.params.orbit_rate_radps == pytest.approx(K_T * orbit_rate(800e3), rel=1e-15)
    f_lab, tau_lab = np.array([[0.3, -0.2, 0.1]]), np.array([[0.01, 0.02, -0.015]])
    f_orbit, tau_orbit = K_M * K_L / K_T**2 * f_lab, K_M * K_L**2 / K_T**2 * tau_lab
    dt_lab = 0.002
    for _ in range(3000):  # 6 s in the lab, 300 s in orbit
        lab.step(f_lab, tau_lab, dt_lab)
        orbit.step(f_orbit, tau_orbit, K_T * dt_lab)
    np.testing.assert_allclose(K_L * lab.position_m, orbit.position_m, rtol=1e-9)
    np.testing.assert_allclose(K_L / K_T * lab.velocity_mps, orbit.velocity_mps, rtol=1e-9)
    np.testing.assert_allclose(lab.attitude_wxyz, orbit.attitude_wxyz, atol=1e-12)
    np.testing.assert_allclose(lab.omega_rel_radps / K_T, orbit.omega_rel_radps, rtol=1e-9)
    assert np.linalg.norm(orbit.velocity_mps - _orbit_units().satellites[0].velocity_mps) > 0.01


def test_the_paper_s_law_is_unchanged():
    """The paper's presets: the ODS integrates the mockup (its mass, its box inertia) with
    the two knobs, at the orbit's own rate; metrics say what it moves as."""
    cfg = load_scenario("free-floating")
    ods = OrbitalSimulator.from_config(cfg)
    sat = cfg.satellites[0]
    assert ods.params.orbit_rate_radps == orbit_rate(cfg.orbit.altitude_m)
    assert (ods.params.force_scale, ods.params.torque_scale) == (0.005, 0.0005)
    np.testing.assert_array_equal(ods.params.inertia_kgm2[0], box_inertia(1.0, sat.size_m))
    body = describe(cfg)["satellites"][0]
    assert body["lab_equivalent_mass_kg"] == pytest.approx(200.0)
    assert body["inertia_vs_uniform_box"] == pytest.approx(10.0)  # not one body: 2000 / 200
    assert summary_line(cfg) == (
        "scaling: the paper's knobs (force x0.005, torque x0.0005); cubesat moves as 200 kg "
        "with 10x a uniform box's inertia")
    default = scaling_of(EmulatorConfig())  # no knobs given: the paper's
    assert (default.force_scale, default.torque_scale) == (1.0, 1 / 2000)


def test_similarity_is_one_body_and_reports_it():
    cfg = _similar(length=2.0, time=10.0, mass=4.0)
    sat = {**SAT, "inertia_kgm2": None}
    cfg = parse_config({**cfg.model_dump(), "satellites": [sat]})
    info = describe(cfg)
    body = info["satellites"][0]
    assert (info["force_scale"], info["torque_scale"]) == (4.0, 16.0)  # k_M, k_M k_L²
    np.testing.assert_allclose(body["inertia_kgm2"], box_inertia(200.0, [0.4, 0.4, 0.2]))
    assert body["inertia_vs_uniform_box"] == pytest.approx(1.0)  # one consistent body
    assert body["mockup_mass_kg"] == 1.0
    assert "a 200 kg satellite on a 1 kg mockup" in info["text"]
    k, c = orbit_equivalent_material(500.0, 20.0, scaling_of(cfg))
    assert (k, c) == pytest.approx((500.0 * 4.0 / 100.0, 20.0 * 10.0 / 2.0))


def test_a_push_s_impulse_on_the_mockup_is_the_virtual_body_s_momentum_under_the_law():
    """Ideal run, one scripted push of J = F Δt in the lab: the virtual satellite's orbit
    momentum changes by k_M k_L / k_T J (CW terms over 0.3 s of a 10x time scale: < 0.1 %)."""
    k_l, k_t, k_m = 2.0, 10.0, 50.0
    cfg = parse_config({
        "scaling": {"law": "similarity", "length": k_l, "time": k_t, "mass": k_m},
        "orbit": {"gravity_gradient": False},
        "satellites": [{"name": "big", "mass_kg": 200.0, "mockup_mass_kg": 1.0}],
        "pulses": [{"satellite": "big", "start_s": 0.1, "end_s": 0.4,
                    "force_N": [0.0, 2.0, 0.0]}],
        "loop": {"duration_s": 0.5}})
    em = Emulator(cfg, mode="ideal")
    em.run(0.5)
    rows, index = em.telemetry.rows(), em.telemetry.index
    v_lab = rows[-1, index["sat1_vy_mps"]] - rows[0, index["sat1_vy_mps"]]
    momentum_orbit = 200.0 * v_lab * k_l / k_t
    assert momentum_orbit == pytest.approx(k_m * k_l / k_t * 2.0 * 0.3, rel=1e-3)


def test_the_arm_carries_the_mockup_s_mass_not_the_satellite_s():
    """hil, a 2000 kg satellite on a 1 kg mockup at rest: the sensor chain compensates
    the mockup; had it taken the satellite's mass, the weight error (tonnes x g) would push
    the satellite away."""
    cfg = load_scenario("free-floating")
    data = cfg.model_dump()
    data["scaling"] = {"law": "similarity"}
    data["orbit"] |= {"force_scale": None, "torque_scale": None}
    data["satellites"][0] |= {"mass_kg": 2000.0, "mockup_mass_kg": 1.0}
    em = Emulator(parse_config(data), mode="hil")
    em.run(1.0)
    v = em.ods.velocity_mps[0]
    assert np.linalg.norm(v) < 1e-5, v
    assert em.arms[0].mockup_mass_kg == 1.0


@pytest.mark.parametrize(("data", "message"), [
    ({"scaling": {"length": 2.0}},
     "scaling: length, time and mass apply under law = 'similarity'"),
    ({"scaling": {"law": "similarity"}, "orbit": {"force_scale": 0.5},
      "satellites": [{"name": "a", "mockup_mass_kg": 1.0}]},
     "orbit.force_scale: derived under scaling.law = 'similarity'"),
    ({"scaling": {"law": "similarity"}, "satellites": [{"name": "a", "mass_kg": 300.0}]},
     "satellites.0.mockup_mass_kg: required under scaling.law = 'similarity' (mass_kg is "
     "the virtual satellite's, 300 kg"),
    ({"scaling": {"law": "similarity", "length": 1.0, "time": 20.0},
      "satellites": [{"name": "a", "mockup_mass_kg": 1.0, "material": "sponge"},
                     {"name": "b", "mockup_mass_kg": 1.0}]},
     "scaling: length 1 and time 20 play velocities at 20 x the orbit's, but the contact's "
     "Hunt-Crossley damping (materials rigid, sponge) makes restitution depend on the "
     "impact speed"),
    ({"scaling": {"law": "similarity", "time": 0.0}}, "scaling.time"),
    ({"scaling": {"law": "similarity", "time": 1e300}}, "scaling.time: Input should be "
                                                        "less than or equal to 1000000"),
    ({"scaling": {"law": "similarity", "time": 1e5},
      "satellites": [{"name": "a", "mockup_mass_kg": 1.0}]},
     "scaling.time: 100000 turns the orbit frame 0.208 rad per loop cycle at 500 Hz; at "
     "most 0.01 (k_T <= 4816 here)"),
])
def test_what_breaks_similarity_is_refused_naming_the_field(data, message):
    with pytest.raises(ConfigError) as err:
        parse_config(data)
    assert message in str(err.value)


def test_a_time_scale_with_contact_is_allowed_where_velocities_are_the_orbit_s():
    cfg = parse_config({
        "scaling": {"law": "similarity", "length": 5.0, "time": 5.0, "mass": 2.0},
        "satellites": [{"name": "a", "mockup_mass_kg": 1.0, "material": "sponge"},
                       {"name": "b", "mockup_mass_kg": 1.0}]})
    assert scaling_of(cfg).velocity == 1.0


def test_the_config_s_orbit_rate_is_the_simulator_s():
    from app.config import _orbit_rate

    for altitude_m in (400e3, 800e3, 35786e3):
        assert _orbit_rate(altitude_m) == orbit_rate(altitude_m)


def test_the_summary_line_names_every_satellite_and_what_it_moves_as():
    from app.config import merge_overrides
    from app.scenarios import load_scenario

    assert summary_line(load_scenario("collision")).endswith(
        "; cubesat and sponge move as 1 kg with 2000x a uniform box's inertia")
    assert summary_line(load_scenario("rendezvous")).endswith(
        "; chaser and target: each a 500 kg satellite on a 1 kg mockup")
    docking = merge_overrides(load_scenario("docking"),
                              {"satellites": {"1": {"mass_kg": 400.0}}})
    assert summary_line(docking).endswith(
        "; chaser: a 100 kg satellite on a 1 kg mockup; target: a 400 kg satellite on a 1 kg "
        "mockup")
