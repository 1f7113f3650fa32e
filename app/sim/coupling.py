"""The ODS coupling: the measured wrenches become the input of the virtual satellites.

Each arm's processed F/T wrench (force in R, torque about the COM in body axes) goes to the
ODS of the satellite that arm carries; a satellite without an arm gets its external wrench
exactly. With ``[passivity] enabled``, the forces of all satellites pass through one
energy tank (:class:`app.sim.passivity.TankPassivity`: time-aligned port power, momentum
kept) and each carried satellite's torque through its own passivity controller. The ODS
applies the force and torque scales of ``[orbit]`` itself (Eqs. 1-6).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.config import PassivityConfig
from app.sim.frames import Bodies
from app.sim.orbital import OrbitalSimulator
from app.sim.passivity import PassivityController, TankPassivity, any_nonzero

__all__ = ["OdsCoupling"]


class OdsCoupling:
    """Measured wrenches → ODS input (with passivity control when enabled).

    carried: the satellites (0-based) that an arm carries; masses_kg: every satellite's
    mass; align_cycles: how old the physical state is that a measured force belongs to.
    """

    def __init__(self, config: PassivityConfig, dt_s: float, carried: Sequence[int],
                 masses_kg: Sequence[float], force_scale: float = 1.0,
                 align_cycles: int = 0) -> None:
        self.enabled = config.enabled and len(carried) > 0
        self.carried = list(carried)
        self.tank: TankPassivity | None = None
        self.torque_pcs: dict[int, PassivityController] = {}
        if not self.enabled:
            return
        self.tank = TankPassivity(dt_s, np.asarray(masses_kg, dtype=float), force_scale,
                                  align_cycles, config.idle_reset_s, config.tank_max_J)
        self.torque_pcs = {s: PassivityController(dt_s, config.idle_reset_s)
                           for s in self.carried}

    def ods_input(self, force_R: np.ndarray, torque_B: np.ndarray, ods: OrbitalSimulator,
                  bodies: Bodies, R_W_R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force in R, torque in body axes) for every satellite's ODS from what was
        measured (N, 3 each); ods: the satellites (virtual side), bodies: where the bodies
        are and how they move in the lab (physical side; for a satellite without an arm,
        the satellite itself)."""
        if not self.enabled:
            return force_R, torque_B
        if any_nonzero(force_R):  # else the tank only counts an idle cycle: no velocities
            force_R = self.tank.step(force_R, ods.velocity_mps, bodies.v_W, R_W_R)
        else:
            self.tank.idle(bodies.v_W)
        torques = torque_B.tolist()  # plain floats for the zero tests (a few satellites)
        w_virtual_B = None
        for s, pc in self.torque_pcs.items():
            t_s = torques[s]
            if t_s[0] == 0.0 and t_s[1] == 0.0 and t_s[2] == 0.0:  # is_zero
                pc.idle()
                continue
            t = torque_B[s]
            if w_virtual_B is None:  # only while a torque acts
                w_virtual_B = ods.omega_rel_radps
                torque_B = torque_B.copy()
            R_W_C = bodies.T_W_C[s, :3, :3]
            torque_B[s] = pc.step(t, w_virtual_B[s], R_W_C.T @ bodies.w_W[s])
        return force_R, torque_B

    def dissipated_J(self) -> dict | None:
        """Energy the passivity layer removed: the force tank's over all satellites, and
        each carried satellite's torque port; None when passivity control is off."""
        if not self.enabled:
            return None
        return {"force": self.tank.dissipated_J,
                "torque": {s: pc.dissipated_J for s, pc in self.torque_pcs.items()}}
