"""Contact-aware wrench estimator: a measured contact force acts along the contact's normal.

While the contact gate is open for a mockup (app/sim/contact_gate.py), the deadbands are
lifted and the sensor's noise reaches the ODS in every direction. In a head-on contact
between two frictionless faces, the part of the measured force across the normal is
pure noise, and so is the torque about the COM: integrated over the open gate, it sent
the satellites off the collision's axis (22° on one seed) and out of the arms' reach.

The lab knows more than the sensor at a contact. It knows the mockups' shapes (boxes of
known size) and, from the arms' joint encoders through forward kinematics, where they
are: a geometric query (the signed-distance query the gate already makes,
:meth:`app.sim.contact.BoxContactModel.clearances`) gives the contact's normal n and its
point p. It knows the materials' friction coefficient μ (configuration). A contact
force lies in the friction cone about n, so the estimate handed to the ODS is the
measured force projected on that cone:

    F_n = max(0, F·n)                       (a contact pushes, never pulls)
    F_t = F − (F·n) n,  clamped to |F_t| ≤ μ |F_n|                                (cone)
    F̂ = F_n n + F_t,    τ̂ = (p − c) × F̂                                          (wrench)

c the mockup's COM (from the same kinematics).

The no-pull clamp rectifies the noise: where the true normal force is near zero (the
gate open just before the touch, the hold while the last of the delayed force arrives,
the sponge's soft end) it passes the noise's positive half only, a push of about 0.4 σ
per cycle. Measured (benchmarks/contact_fidelity.py ``--seeds --factors``, seeds 0–29 and
0–19) it moves the mean restitution error by +57 points for the sponge and −10 points for
rigid on rigid: an unbiased estimate of a force that is near zero must sometimes be
negative. So ``[wrench] contact_no_pull`` (default off) chooses it; without it,
F_n = F·n as measured, and the tangential clamp uses |F_n|. The torque about the COM is the moment
of the estimated force at the contact point: a head-on contact through the COMs hands
the ODS no torque, as the contact itself exerts none. Nothing here reads the simulated
contact's force or its material law (stiffness, damping): only the geometry and μ.

What it cannot see: a second force on the mockup (an operator's hand) during the
contact. It is therefore applied only where the gate names one contact for the mockup
and, for two carried mockups, where their sensors agree with Newton's third law
(:func:`app.sim.contact_gate.pair_consistent`): a push on either is passed as measured.
"""

from __future__ import annotations

import math

import numpy as np

from app.sim.rotations import cross3_floats, minus3_floats

__all__ = ["cone_projection", "contact_wrench_W"]


def cone_projection(force_W: np.ndarray, normal_W: np.ndarray, mu: float,
                    no_pull: bool = True) -> np.ndarray:
    """(3,) the force on the friction cone about the unit ``normal_W`` (the direction the
    contact pushes the body): its normal part kept if it pushes (with ``no_pull``, zero
    if it would pull; without, kept as measured), its tangential part clamped to μ times
    the normal part's magnitude (module doc, cone)."""
    f_n = float(force_W.dot(normal_W))  # ndarray.dot: `@`'s dot kernel, less overhead
    if f_n <= 0.0 and no_pull:
        return np.zeros(3)
    tangential = force_W - f_n * normal_W
    t = math.sqrt(float(tangential.dot(tangential)))
    limit = mu * abs(f_n)
    if t > limit:
        tangential = tangential * (limit / t) if t > 0.0 else tangential
    return f_n * normal_W + tangential


def contact_wrench_W(force_W: np.ndarray, normal_W: np.ndarray, point_W: np.ndarray,
                     com_W: np.ndarray, mu: float,
                     no_pull: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(force, torque about the COM), W axes: the measured force on the cone, acting at
    the contact point (module doc, wrench)."""
    f = cone_projection(force_W, normal_W, mu, no_pull)
    r = minus3_floats(point_W.tolist(), com_W.tolist())  # r × f on plain floats: the
    return f, np.array(cross3_floats(r, f.tolist()))     # same operations, the same bits
