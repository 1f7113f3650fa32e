"""The ODS coupling: each arm's measured wrench becomes the input of its virtual satellite.

The processed F/T wrench of an arm (force in R, torque about the COM in body axes) goes to
the ODS of the satellite that arm carries, through that arm's passivity controllers when
``[passivity] enabled`` (:mod:`app.sim.passivity`); the ODS applies the force and torque
scales of ``[orbit]`` itself (Eqs. 1-6).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.config import PassivityConfig
from app.sim.ft_sensor import ProcessedWrench
from app.sim.orbital import OrbitalSimulator
from app.sim.passivity import PassivityController, is_zero

__all__ = ["OdsCoupling"]


class OdsCoupling:
    """Measured wrench of each arm → ODS input of its satellite (with passivity control)."""

    def __init__(self, config: PassivityConfig, dt_s: float, satellites: Sequence[int]) -> None:
        self.passivity: dict[int, tuple[PassivityController, PassivityController]] = {}
        if config.enabled:
            for s in satellites:
                self.passivity[s] = (PassivityController(dt_s, config.idle_reset_s),
                                     PassivityController(dt_s, config.idle_reset_s))

    def ods_input(self, satellite: int, measured: ProcessedWrench, ods: OrbitalSimulator,
                  v_W: np.ndarray, w_W: np.ndarray, R_W_C: np.ndarray,
                  R_W_R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force in R, torque in body axes) for the ODS of `satellite`, from the wrench
        measured on its mockup moving at v_W, w_W (lab) with attitude R_W_C."""
        force, torque = measured.force_R_N, measured.torque_B_Nm
        pcs = self.passivity.get(satellite)
        if pcs is None:
            return force, torque
        pc_f, pc_t = pcs
        if is_zero(force):  # the velocities are only needed while something acts
            pc_f.idle()
        else:
            force = pc_f.step(force, ods.velocity_mps[satellite], R_W_R.T @ v_W)
        if is_zero(torque):
            pc_t.idle()
        else:
            torque = pc_t.step(torque, ods.omega_rel_radps[satellite], R_W_C.T @ w_W)
        return force, torque

    def dissipated_J(self) -> dict[int, dict[str, float]] | None:
        """Energy each satellite's controllers removed (force and torque ports); None when
        passivity control is off."""
        if not self.passivity:
            return None
        return {s: {"force": f.dissipated_J, "torque": t.dissipated_J}
                for s, (f, t) in self.passivity.items()}
