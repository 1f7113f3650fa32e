"""CW rendezvous guidance: two-impulse transfers between hold points (orbit units).

Clohessy–Wiltshire (DESIGN.md, Eqs. 1-3) in closed form, [r; v](t) = Φ(t) [r; v](0)
(:func:`app.sim.orbital.cw_state_transition`), with Φ split into 3x3 blocks
[[Φrr, Φrv], [Φvr, Φvv]]. A transfer from r0 to rf in time T needs, right after the
first impulse, v0⁺ = Φrv⁻¹ (rf − Φrr r0), and arrives with vf⁻ = Φvr r0 + Φvv v0⁺; the
two impulses are Δv1 = v0⁺ − v0 and Δv2 = vf − vf⁻. Φrv is singular at T = k·2π/Ω in
plane (a whole orbit) and at T = k·π/Ω out of plane (its block is sin ΩT / Ω): such a
transfer time is refused.
"""

from __future__ import annotations

import numpy as np

from app.sim.orbital import cw_state_transition

__all__ = ["SingularTransfer", "two_impulse_transfer", "vbar_hold_points"]


class SingularTransfer(ValueError):
    """No CW transfer takes exactly this long (Φrv is singular)."""


def two_impulse_transfer(r0_m, v0_mps, rf_m, vf_mps, transfer_s: float,
                         orbit_rate_radps: float) -> tuple[np.ndarray, np.ndarray]:
    """(Δv1, Δv2) in R of the CW transfer from (r0, v0) to (rf, vf) in transfer_s."""
    phi = cw_state_transition(orbit_rate_radps, transfer_s)
    rr, rv, vr, vv = phi[:3, :3], phi[:3, 3:], phi[3:, :3], phi[3:, 3:]
    if abs(np.linalg.det(rv)) < 1e-9 * (transfer_s ** 3):
        raise SingularTransfer(
            f"transfer_s: {transfer_s:g} s is a whole number of half orbits (pi / Omega = "
            f"{np.pi / orbit_rate_radps:.0f} s): no CW transfer takes exactly that long")
    r0, rf = np.asarray(r0_m, float), np.asarray(rf_m, float)
    v0_plus = np.linalg.solve(rv, rf - rr @ r0)
    vf_minus = vr @ r0 + vv @ v0_plus
    return v0_plus - np.asarray(v0_mps, float), np.asarray(vf_mps, float) - vf_minus


def vbar_hold_points(start_m: float, end_m: float, count: int) -> np.ndarray:
    """``count`` hold points on V-bar (R's y axis) from y = start_m to y = end_m, evenly
    spaced (rows of R positions), the last one end_m."""
    if count < 1:
        raise ValueError("count: at least one hold point")
    y = np.linspace(start_m, end_m, count + 1)[1:]
    return np.column_stack([np.zeros(count), y, np.zeros(count)])
