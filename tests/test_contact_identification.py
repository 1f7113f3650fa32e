"""Online Hunt–Crossley identification (app/sim/contact_identification.py): against the
exact 1-D impact of known laws, with and without noise, and in the emulated collision."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from app.config import merge_overrides
from app.runs.headless import collision_of
from app.scenarios import load_scenario
from app.sim.contact_identification import HuntCrossleyFit
from app.sim.loop import Emulator

SPONGE = (487.8, 19.52)  # the collision's sponge on rigid: k (N/m), c (s/m)
RIGID = (1.0e4, 0.5)  # rigid on rigid
NO_NOISE = {"sensor": {"noise_force_N": 0.0, "noise_torque_Nm": 0.0}}


def impact(k: float, c: float, m_red_kg: float = 0.5, v0_mps: float = 0.16,
           rate_hz: float = 500.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d, ḋ, F) sampled at rate_hz through the exact 1-D impact m d̈ = −F, F = max(0,
    k d (1 + c ḋ)), from d = 0 at ḋ = v0 until the bodies part."""
    def rhs(_t, s):
        return [s[1], -max(0.0, k * s[0] * (1.0 + c * s[1])) / m_red_kg]

    def parted(_t, s):
        return s[0]
    parted.terminal, parted.direction = True, -1
    t = np.arange(1, 200) / rate_hz
    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, v0_mps], t_eval=t, events=parted,
                    method="DOP853", rtol=1e-12, atol=1e-14)
    d, v = sol.y
    return d, v, np.maximum(0.0, k * d * (1.0 + c * v))


def fit_of(d, v, f) -> HuntCrossleyFit:
    fit = HuntCrossleyFit()
    for x in zip(d, v, f, strict=True):
        fit.update(*x)
    return fit


@pytest.mark.parametrize("law", [SPONGE, RIGID], ids=["sponge", "rigid"])
def test_noiseless_samples_of_an_impact_give_its_law(law):
    d, v, f = impact(*law)
    fit = fit_of(d, v, f)
    assert fit.samples == len(d) > 5
    assert fit.stiffness_Npm == pytest.approx(law[0], rel=1e-8)
    assert fit.damping_spm == pytest.approx(law[1], rel=1e-8)
    np.testing.assert_allclose([fit.predict(*x) for x in zip(d, v, strict=True)], f,
                               rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("law", [SPONGE, RIGID], ids=["sponge", "rigid"])
def test_noisy_samples_converge_to_the_law_within_the_least_squares_error(law):
    """400 impacts with the fused data-sheet noise (1.18 N per sample): the identified k
    and λ = k c are unbiased (mean within 4 standard errors of the truth) and scatter as
    least squares predicts, σ² (ΦᵀΦ)⁻¹ (sd within 15 %: 400 draws know an sd to 3.5 %)."""
    sigma = 1.67 / np.sqrt(2.0)
    d, v, f = impact(*law)
    rng = np.random.default_rng(3)
    fits = [fit_of(d, v, f + sigma * rng.standard_normal(len(f))) for _ in range(400)]
    theta = np.array([[x.stiffness_Npm, x.stiffness_Npm * x.damping_spm] for x in fits])
    phi = np.column_stack([d, d * v])
    sd_ls = sigma * np.sqrt(np.diag(np.linalg.inv(phi.T @ phi)))
    truth = np.array([law[0], law[0] * law[1]])
    se = theta.std(axis=0, ddof=1) / np.sqrt(len(fits))
    assert np.all(np.abs(theta.mean(axis=0) - truth) < 4.0 * se)
    np.testing.assert_allclose(theta.std(axis=0, ddof=1), sd_ls, rtol=0.15)


def test_the_prediction_averages_the_noise_as_samples_accrue():
    """Along the sponge impact, the identified force's error after the first samples is
    well under the sensor's: its rms over the contact is under half the noise's."""
    sigma = 1.67 / np.sqrt(2.0)
    d, v, f = impact(*SPONGE)
    rng = np.random.default_rng(8)
    errors = []
    for _ in range(100):
        fit = HuntCrossleyFit()
        for x, y, z in zip(d, v, f + sigma * rng.standard_normal(len(f)), strict=True):
            fit.update(x, y, z)
            errors.append(fit.predict(x, y) - max(0.0, SPONGE[0] * x * (1 + SPONGE[1] * y)))
    assert np.sqrt(np.mean(np.square(errors))) < 0.5 * sigma


def test_one_sample_is_returned_and_no_overlap_gives_no_force():
    fit = HuntCrossleyFit()
    assert fit.predict(0.002, 0.1) == 0.0  # nothing learnt yet
    fit.update(-0.001, 0.1, 5.0)  # apart: not a sample
    assert fit.samples == 0
    fit.update(0.002, 0.1, 1.3)
    assert fit.predict(0.002, 0.1) == pytest.approx(1.3, rel=1e-6)
    assert fit.predict(0.0, 0.1) == 0.0
    fit.update(0.002, -0.1, -0.4)  # a pulling law is clamped: a contact never pulls
    assert fit.predict(0.002, -0.2) == 0.0


def _collision_run(*overrides: dict) -> Emulator:
    cfg = load_scenario("collision")
    for o in (*overrides, {"wrench": {"contact_force": "identified"}, "loop": {"seed": 0}}):
        cfg = merge_overrides(cfg, o)
    em = Emulator(cfg)
    em.run(3.6)  # the contact is at 3.1-3.3 s
    return em


def test_the_collision_identifies_its_contact_law_from_the_lab_s_measurements():
    """Noiseless: the fit of the mockups' geometry (FK) and the fused F/T force is the
    contact law exactly; with the data sheet's noise (seed 0), within 4 standard errors
    of least squares (σ² A⁻¹ with the noise the calibration measured)."""
    em = _collision_run(NO_NOISE)
    k, c = em.interaction.contact.law(0, 1)
    fit = em.contact_fits[(0, 1)]
    assert fit.samples > 20
    assert fit.stiffness_Npm == pytest.approx(k, rel=1e-5)
    assert fit.damping_spm == pytest.approx(c, rel=1e-4)
    restitution = collision_of(em)["restitution"]

    em = _collision_run()
    fit = em.contact_fits[(0, 1)]
    sigma = np.sqrt(np.mean([np.trace(a.processor.calibration.force_noise_cov_S) / 3
                             for a in em.arms]) / 2.0)  # the fused estimate's
    scale = np.array([1e-3, 1e-3 * 0.1])  # θ in the fit's units: k·1e-3, λ·1e-4
    sd = sigma * np.sqrt(np.diag(np.linalg.inv(fit.A))) / scale
    got = np.array([fit.stiffness_Npm, fit.stiffness_Npm * fit.damping_spm])
    assert np.all(np.abs(got - [k, k * c]) < 4.0 * sd)
    assert abs(collision_of(em)["restitution"] - restitution) < 0.5 * restitution


def test_the_float_sums_are_the_array_arithmetic_bit_for_bit():
    """The fit's sums on plain floats give the arrays' A += φ φᵀ, b += φ F and
    θ = solve(A + ε I, b) to the bit, over random samples (zero rates and forces, pulls,
    apart samples among them); a copy of the fit (a replicate's, copy_state) learns
    alone."""
    from copy import deepcopy

    from app.sim.contact_identification import RIDGE

    rng = np.random.default_rng(7)
    fit = HuntCrossleyFit()
    A, b = np.zeros((2, 2)), np.zeros(2)
    for k in range(400):
        d = float(rng.uniform(-0.002, 0.01))
        rate = 0.0 if k % 7 == 0 else float(rng.normal(0.0, 0.2))
        f = 0.0 if k % 11 == 0 else float(rng.normal(3.0, 2.0))
        fit.update(d, rate, f)
        if d > 0.0:
            phi = fit.regressor(d, rate)
            A += phi[:, None] * phi[None, :]
            b += phi * f
            theta = np.linalg.solve(A + RIDGE * np.eye(2), b)
            assert fit._theta.tobytes() == theta.tobytes()
            assert fit.predict(d, rate) == max(0.0, float(theta @ phi))
    assert fit.A.tobytes() == A.tobytes() and fit.b.tobytes() == b.tobytes()
    twin = deepcopy(fit)
    twin.update(0.004, 0.1, 2.0)
    assert fit.A.tobytes() == A.tobytes() and fit.samples == twin.samples - 1
