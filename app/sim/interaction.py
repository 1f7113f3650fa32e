"""The physical interaction on the actual mockups: contact between them and the operator's hand.

In the lab the mockups touch each other and the operator's hand, wherever the arms
actually hold them (DESIGN.md "The loop"); in an ideal run there are no arms and the
bodies are where the ODS has them. Either way this module turns the bodies' poses and
velocities into the external wrench on each body (lab axes, moment about its COM): what
the F/T sensors then measure, or, in an ideal run, what the ODS receives exactly.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.sim.contact import BoxContactModel
from app.sim.frames import Bodies, ods_states_W
from app.sim.hand import OperatorHand
from app.sim.orbital import OrbitalSimulator

__all__ = ["Bodies", "PhysicalInteraction", "actual_bodies", "body_torque_B", "ods_bodies"]


def ods_bodies(T_W_R: np.ndarray, ods: OrbitalSimulator) -> Bodies:
    """The satellites where the ODS has them (the ideal run's bodies)."""
    n = ods.y.shape[0]
    T_W_C, v_unused = np.empty((n, 4, 4)), np.empty((n, 3))
    ods_states_W(T_W_R, ods.y, T_W_C, v_unused)
    v_W = ods.velocity_mps @ T_W_R[:3, :3].T
    omega_rel = ods.omega_rel_radps
    w_W = np.array([T_W_C[i, :3, :3] @ omega_rel[i] for i in range(n)])
    return Bodies(T_W_C, v_W, w_W)


def actual_bodies(T_W_R: np.ndarray, ods: OrbitalSimulator, rigs: Sequence) -> Bodies:
    """The actual mockups: each carried one where its arm holds it (forward kinematics);
    a satellite without an arm where the ODS has it, not turning."""
    n = ods.y.shape[0]
    if n == 1 and len(rigs) == 1:  # the arm's forward kinematics, as (1, ...) views
        _, T, v, w = rigs[0].mockup_state_W()  # (kept arrays, which nothing writes into)
        return Bodies(T[None], v[None], w[None])
    T_W_C, v_W, w_W = np.empty((n, 4, 4)), np.empty((n, 3)), np.zeros((n, 3))
    if len(rigs) < n:  # else every satellite is carried (one robot each): all FK below
        ods_states_W(T_W_R, ods.y, T_W_C, v_W)
    for rig in rigs:
        s = rig.satellite
        _, T_W_C[s], v_W[s], w_W[s] = rig.mockup_state_W()
    return Bodies(T_W_C, v_W, w_W)


def body_torque_B(wrench_W: np.ndarray, T_W_C: np.ndarray) -> np.ndarray:
    """The moment (about the COM) of an external wrench in the body's axes, as the ODS
    takes it: what a perfect sensor would hand over (ideal runs, satellites without an
    arm); the force goes to the ODS in R, ``wrench_W[:3] · R_W_R``."""
    return T_W_C[:3, :3].T @ wrench_W[3:]


class PhysicalInteraction:
    """Contact between the bodies plus the operator's hand, as external wrenches."""

    def __init__(self, contact: BoxContactModel, hand: OperatorHand) -> None:
        self.contact = contact
        self.hand = hand
        self.contact_active = False
        """Whether any pair of bodies pushed on each other in the last call."""
        self.touching: frozenset[frozenset[int]] = frozenset()
        """The pairs of bodies that overlapped in the last call (each a set of two)."""
        self.hand_acting = np.zeros(contact.n, dtype=bool)
        """Per body, whether the operator's hand pushed (or twisted) it in the last call."""
        self._hand_acted = False  # whether hand_acting may hold a True

    def wrenches_W(self, bodies: Bodies, t_s: float) -> np.ndarray:
        """(N, 6) external wrench on each body at t_s: force in W, moment about its COM."""
        T_W_C = bodies.T_W_C
        contact_W = self._contact_W(bodies)
        if self.hand.idle(t_s):  # the hand's wrenches are all zero: nothing to add
            if self._hand_acted:  # else hand_acting is all False already
                self.hand_acting = np.zeros(self.contact.n, dtype=bool)
                self._hand_acted = False
            return contact_W
        hand_W = self.hand.wrenches_W(t_s, T_W_C[:, :3, 3], T_W_C[:, :3, :3], bodies.v_W,
                                      bodies.w_W)
        self.hand_acting = np.any(hand_W != 0.0, axis=1)
        self._hand_acted = True
        return contact_W + hand_W

    def _contact_W(self, bodies: Bodies) -> np.ndarray:
        """(N, 6) the contact wrenches (:meth:`BoxContactModel.compute`); updates
        :attr:`contact_active` and :attr:`touching`. In free flight (no pair within
        reach, :meth:`BoxContactModel.apart`) what compute then gives, without its call."""
        contact = self.contact
        if contact.apart(bodies.T_W_C):
            self.contact_active, self.touching = False, frozenset()
            return np.zeros((contact.n, 6))
        result = contact.compute(bodies.T_W_C, bodies.v_W, bodies.w_W)
        if result.contacts:
            self.contact_active = any(c.normal_force_N > 0 for c in result.contacts)
            self.touching = frozenset(frozenset((c.a, c.b)) for c in result.contacts)
        else:
            self.contact_active, self.touching = False, frozenset()
        return result.wrench_W
