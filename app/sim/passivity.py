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

Two ports, one contact: a contact between two mockups acts on both satellites, and trimming
each arm's force on its own breaks the momentum balance (5 % sponge, 22 % rigid). The
force ports of all satellites that are being acted on are therefore watched together by
:class:`TankPassivity`, an energy tank (Franken et al., "Bilateral telemanipulation with
time delays: a two-layer approach combining passivity and transparency", IEEE T-RO 2011;
Ferraguti et al., "An energy tank-based interactive control architecture", ICRA 2013):

    T(k) = T(k−1) + dt Σ_i F_i · v_p,i(k − d) − dt Σ_i F'_i · v_v,i(k)                (tank)

F_i the measured force on mockup i, v_p,i its velocity when that force was measured (d
cycles ago: the sensor's delay and the filter's lag — the *time-aligned* port power),
F'_i what satellite i receives, v_v,i its velocity. The virtual satellites never gain
more energy than the mockups received from the contact: when a cycle would leave T < 0,
a damper between the satellites takes out the excess,

    F'_i = F_i − β m_i (v_v,i − v_cm),   v_cm = Σ m_i v_v,i / Σ m_i,                      (PC2)

a set of internal forces (Σ m_i (v_v,i − v_cm) = 0): momentum stays balanced, the
correction is split between the satellites by their masses. β is capped so that no
satellite's force turns against itself (a contact pushes; the damper may take the push
away, never make it a pull); what the cap leaves is carried to the next cycles. With only
one satellite acted on (the other's sensor inside its deadband, an operator's push) there
is no internal force to apply: the tank counts, nothing is corrected. T starts each contact full,
at ``tank_max_J``: a budget that covers what the sensor noise drains from it (noise
pushes the satellite first and the mockup a few cycles later, so the noise's own power
looks like energy created); it is capped there, so that energy the contact dissipated
early is not handed back late.

Scales: the ODS applies s·F to a satellite of mass m, which moves as a body of mass m/s
under F; both sums above use the unscaled F, so the tank counts energy in the physical
port's units whatever [orbit] force_scale is. The torque ports (each satellite's own, a
:class:`PassivityController` with the angular velocities; torque_scale enters the same
way) have no momentum to keep and stay single-port.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PassivityController", "TankPassivity", "any_nonzero", "is_zero"]


def is_zero(v: np.ndarray) -> bool:
    """Whether a 3-vector is exactly zero (inside the deadband); cheaper than ndarray.any."""
    return v[0] == 0.0 and v[1] == 0.0 and v[2] == 0.0


def any_nonzero(vectors: np.ndarray) -> bool:
    """Whether any row of an (N, 3) array is not exactly zero (a port acted on); on plain
    floats, cheaper than ndarray.any for a few rows."""
    return any(v[0] != 0.0 or v[1] != 0.0 or v[2] != 0.0 for v in vectors.tolist())


def _no_reversal_beta(force: np.ndarray, per_beta: np.ndarray) -> float:
    """The largest β for which no force F_i − β d_i turns against F_i (F'_i · F_i ≥ 0):
    the damper may take a push away, never turn it into a pull."""
    along = np.einsum("ij,ij->i", per_beta, force)
    squared = np.einsum("ij,ij->i", force, force)
    braking = along > 0.0
    if not braking.any():
        return math.inf
    return float(np.min(squared[braking] / along[braking]))


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
        dt = self.dt_s  # ndarray.dot: `@`'s dot kernel for 3-vectors, less overhead
        self.energy_J += dt * float(force.dot(v_physical - v_virtual))
        power = float(force.dot(v_virtual))
        if self.energy_J >= 0.0 or power <= 0.0:
            return force
        vv = float(v_virtual.dot(v_virtual))
        beta = min(-self.energy_J / (vv * dt), power / vv)
        removed_J = beta * vv * dt
        self.energy_J += removed_J
        self.dissipated_J += removed_J
        return force - beta * v_virtual


class TankPassivity:
    """Energy tank over the force ports of all satellites (see the module doc: tank, PC2).

    masses_kg: (N,) satellite masses; force_scale: what the ODS multiplies the force by;
    align_cycles: d, how many cycles old the physical state is that a measured force
    belongs to; tank_max_J: the tank's cap. One cycle's damper at most halves the
    satellites' relative velocities (β ≤ m / (2 s dt) per unit mass); a deficit beyond
    that is carried to the next cycle.
    """

    def __init__(self, dt_s: float, masses_kg: np.ndarray, force_scale: float,
                 align_cycles: int, idle_reset_s: float, tank_max_J: float) -> None:
        if not dt_s > 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        self.dt_s = float(dt_s)
        self.masses_kg = np.asarray(masses_kg, dtype=float)
        if not force_scale >= 0.0:
            raise ValueError(f"force_scale must be >= 0, got {force_scale}")
        # the satellites feel s·F: at s = 0 no damper moves them, none is too strong
        self.beta_max = 0.5 / (force_scale * self.dt_s) if force_scale > 0.0 else math.inf
        self.align_cycles = int(align_cycles)
        self.idle_reset_cycles = int(round(idle_reset_s / dt_s))
        self.tank_max_J = float(tank_max_J)
        self.reset()

    def reset(self) -> None:
        """Full tank, no history (start of a run)."""
        self.tank_J = self.tank_max_J
        self.dissipated_J = 0.0
        self._idle_cycles = 0
        self._history: list[np.ndarray] = []

    def _aligned(self, v_physical: np.ndarray) -> np.ndarray:
        """The physical velocities of d cycles ago (the oldest kept until there are d)."""
        self._history.append(v_physical)
        if len(self._history) > self.align_cycles + 1:
            del self._history[0]
        return self._history[0]

    def idle(self, v_physical: np.ndarray) -> None:
        """One cycle in which no satellite is acted on (every force exactly zero: what
        :meth:`step` does with such forces): the physical velocities are kept for the
        alignment, the idle time counts, the tank refills after ``idle_reset_s``."""
        self._aligned(v_physical)
        self._idle_cycles += 1
        if self._idle_cycles >= self.idle_reset_cycles:
            self.tank_J = self.tank_max_J

    def step(self, force: np.ndarray, v_virtual: np.ndarray,
             v_physical: np.ndarray, R_W_R: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) forces for the satellites from the measured (N, 3) ones; v_virtual: the
        satellites' velocities now, v_physical: the bodies' velocities now (for a satellite
        without an arm, its own; kept, not copied), in R, or in the lab W when R_W_R is
        given: then turned into R (``v_physical @ R_W_R``, the same product) only in a
        cycle that uses it. A satellite with zero force is not part of the port."""
        acted = [f[0] != 0.0 or f[1] != 0.0 or f[2] != 0.0  # not is_zero, on plain floats
                 for f in force.tolist()]
        if not any(acted):
            self.idle(v_physical)
            return force
        v_p = self._aligned(v_physical)
        self._idle_cycles = 0
        if R_W_R is not None:
            v_p = v_p.dot(R_W_R)  # `@`'s gemm, less overhead
        dt = self.dt_s
        tank = self.tank_J + dt * float(np.sum(force * (v_p - v_virtual)))
        out = force
        if tank < 0.0 and sum(acted) >= 2:
            acted = np.array(acted)
            m = self.masses_kg[acted]
            v = v_virtual[acted]
            rel = v - (m @ v) / m.sum()
            damping_W = float(np.sum(m * np.einsum("ij,ij->i", rel, rel)))  # per unit β
            if damping_W > 0.0:
                beta = min(-tank / (damping_W * dt), self.beta_max,
                           _no_reversal_beta(force[acted], m[:, None] * rel))
                out = force.copy()
                out[acted] -= beta * m[:, None] * rel
                tank += beta * damping_W * dt
                self.dissipated_J += beta * damping_W * dt
        self.tank_J = min(tank, self.tank_max_J)
        return out
