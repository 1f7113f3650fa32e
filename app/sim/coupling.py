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
from app.sim.passivity import PassivityController, TankPassivity, is_zero

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
        self.tank = TankPassivity(dt_s, np.asarray(masses_kg, dtype=float), force_scale,
                                  align_cycles, config.idle_reset_s, config.tank_max_J)
        self.torque_pcs = {s: PassivityController(dt_s, config.idle_reset_s)
                           for s in self.carried}

    def ods_input(self, force_R: np.ndarray, torque_B: np.ndarray, v_virtual_R: np.ndarray,
                  v_physical_R: np.ndarray, w_virtual_B: np.ndarray,
                  w_physical_B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force in R, torque in body axes) for every satellite's ODS from what was
        measured (N, 3 each). v_*: COM velocities in R; w_*: angular velocities relative to
        R in body axes; virtual: the satellites', physical: the bodies' (for a satellite
        without an arm, its own)."""
        if not self.enabled:
            return force_R, torque_B
        force_R = self.tank.step(force_R, v_virtual_R, v_physical_R)
        torque_B = torque_B.copy()
        for s, pc in self.torque_pcs.items():
            if is_zero(torque_B[s]):
                pc.idle()
            else:
                torque_B[s] = pc.step(torque_B[s], w_virtual_B[s], w_physical_B[s])
        return force_R, torque_B

    def dissipated_J(self) -> dict | None:
        """Energy the passivity layer removed: the force tank's over all satellites, and
        each carried satellite's torque port; None when passivity control is off."""
        if not self.enabled:
            return None
        return {"force": self.tank.dissipated_J,
                "torque": {s: pc.dissipated_J for s, pc in self.torque_pcs.items()}}
