"""Passivity observer and energy-bounding controller on an arm's emulation port.

Why: the loop measures a contact force on the *actual* mockup, which lags the ODS pose it
tracks (sensor, filter, deadband, VFDM and servo lag), and hands that force to the
*virtual* satellite. Lag turns a dissipative contact into an energy source (DESIGN.md
"Fidelity"): while the bodies press together the arm keeps driving its mockup into the
contact after the virtual satellite has slowed, and the energy the arm pushed into the
contact comes back as a push on the virtual satellite. Measured here: the sponge
collision's restitution is 1.6 in hil against 0.30 in the ideal run.

The port is passive when the virtual satellite never receives more energy than the
physical port delivered. With the measured force F, the mockup's velocity v_p and the
satellite's velocity v_v (R frame), the passivity observer (PO) integrates

    E(k) = Σ_j dt · F_j · (v_p,j − v_v,j)                                   (PO)

(Hannaford & Ryu, "Time-domain passivity control of haptic interfaces", IEEE T-RA 2002;
for robot-based satellite emulation, De Stefano, Balachandran & Secchi, IEEE T-RO 2020).
E < 0 means the emulation has created energy. The controller then removes the excess from
the force's *accelerating* part only, by a variable damper on the virtual side:

    F_out = F − β v_v,   β = min(−E / (|v_v|² dt), (F · v_v) / |v_v|²),  F · v_v > 0   (PC)

so it never brakes harder than cancelling the push along v_v (|F_out| ≤ |F|, and a force
that decelerates the satellite passes unchanged), and it books what it removed back into
E. Only a velocity *difference* enters E, so the balance is the same in any frame moving
uniformly with respect to the lab.

The observer forgets a debt once the port has been idle (measured force exactly zero,
i.e. inside the deadband) for ``idle_reset_s``: each contact is balanced on its own.

Limitation: the controller treats the environment as passive. An active source on the
port (an operator's push) is throttled to what the arm actually follows, so scenarios
with pushes keep it off.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PassivityController", "is_zero"]


def is_zero(v: np.ndarray) -> bool:
    """Whether a 3-vector is exactly zero (inside the deadband); cheaper than ndarray.any."""
    return v[0] == 0.0 and v[1] == 0.0 and v[2] == 0.0


class PassivityController:
    """Passivity observer + energy-bounding controller for one 3-D port.

    Units are those of the port: force N with velocities m/s, or torque N·m with angular
    velocities rad/s. The force is the unscaled measured one; the ODS applies its scales.
    """

    def __init__(self, dt_s: float, idle_reset_s: float) -> None:
        if not dt_s > 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        if not idle_reset_s >= 0.0:
            raise ValueError(f"idle_reset_s must be >= 0, got {idle_reset_s}")
        self.dt_s = float(dt_s)
        self.idle_reset_cycles = int(round(idle_reset_s / dt_s))
        self.reset()

    def reset(self) -> None:
        """Forget the energy balance (start of a run)."""
        self.energy_J = 0.0
        self.dissipated_J = 0.0
        self._idle_cycles = 0

    def idle(self) -> None:
        """One cycle with zero measured force (what :meth:`step` does with one)."""
        self._idle_cycles += 1
        if self._idle_cycles >= self.idle_reset_cycles:
            self.energy_J = 0.0

    def step(self, force: np.ndarray, v_virtual: np.ndarray, v_physical: np.ndarray) -> np.ndarray:
        """Observe one cycle; return the force for the virtual satellite (PO, then PC)."""
        if is_zero(force):
            self.idle()
            return force
        self._idle_cycles = 0
        dt = self.dt_s
        self.energy_J += dt * float(force @ (v_physical - v_virtual))
        power = float(force @ v_virtual)
        if self.energy_J >= 0.0 or power <= 0.0:
            return force
        vv = float(v_virtual @ v_virtual)
        beta = min(-self.energy_J / (vv * dt), power / vv)
        removed_J = beta * vv * dt
        self.energy_J += removed_J
        self.dissipated_J += removed_J
        return force - beta * v_virtual
