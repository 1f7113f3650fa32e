"""The converged ideal reference: the contact law integrated within the ODS step.

DESIGN.md "Fidelity": the ideal run is what the robot-in-the-loop emulation is measured
against, so it must itself be right. A hil cycle holds the measured force over its 2 ms
(the sensor reads once a cycle), but a stiff contact lasts only a few cycles, and holding
its force over each made the ideal rigid–rigid impact gain energy (restitution 1.175).

Here a cycle of an ideal run that starts or ends in contact is integrated in ``n``
sub-steps of h = dt / n. Each sub-step is a Heun (predictor–corrector) step of the contact:
the external wrench at the sub-step's start, W0, moves the ODS (RK4) to a predicted state,
the wrench there, W1, corrects it, and the sub-step is taken with (W0 + W1) / 2, the
trapezoidal rule on the force: second order in h, with the ODS's own dynamics (Eqs. 1–7)
by RK4 as in every cycle. The operator's hand acts as in the rest of the cycle. The cycle
hands back the mean wrench over its sub-steps, so that the telemetry's force columns
integrate to the impulse exchanged. A satellite's own actuation (app/sim/gnc.py, held over
the cycle) acts in every sub-step on top of the external wrench, and is not in the mean.
"""

from __future__ import annotations

import numpy as np

from app.sim.interaction import PhysicalInteraction, body_torque_B, ods_bodies
from app.sim.orbital import OrbitalSimulator

__all__ = ["exact_input", "substepped_advance"]


def exact_input(interaction: PhysicalInteraction, ods: OrbitalSimulator, T_W_R: np.ndarray,
                t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(force in R, torque in body axes) of the external wrenches on the ODS's bodies."""
    bodies = ods_bodies(T_W_R, ods)
    external_W = interaction.wrenches_W(bodies, t_s)
    force_R = external_W[:, :3] @ T_W_R[:3, :3]
    torque_B = np.array([body_torque_B(external_W[i], bodies.T_W_C[i])
                         for i in range(len(external_W))])
    return force_R, torque_B


def substepped_advance(ods: OrbitalSimulator, interaction: PhysicalInteraction,
                       T_W_R: np.ndarray, t_s: float, dt_s: float, n: int,
                       own: tuple[np.ndarray, np.ndarray] | None = None,
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(state dt_s later, mean external force in R, mean external torque in body axes)
    with the contact integrated in n Heun sub-steps; ``own``: the satellites' own
    (force, torque) in ODS-input units, held, added in every sub-step; ods itself is not
    changed."""
    own_f, own_t = (0.0, 0.0) if own is None else own
    h = dt_s / n
    sub = OrbitalSimulator(ods.params, ods.y.copy(), ods.t_s)
    force_sum, torque_sum = np.zeros_like(ods.y[:, :3]), np.zeros_like(ods.y[:, :3])
    for _ in range(n):
        f0, t0 = exact_input(interaction, sub, T_W_R, t_s)
        predicted = OrbitalSimulator(ods.params, sub.advance(f0 + own_f, t0 + own_t, h),
                                     sub.t_s + h)
        f1, t1 = exact_input(interaction, predicted, T_W_R, t_s)
        f, t = 0.5 * (f0 + f1), 0.5 * (t0 + t1)
        sub.commit(sub.advance(f + own_f, t + own_t, h), h)
        force_sum += f
        torque_sum += t
    return sub.y, force_sum / n, torque_sum / n
