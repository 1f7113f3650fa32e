"""Dynamic scaling: the virtual satellite the ODS integrates vs the mockup the arm carries.

A satellite in orbit (mass m, inertia I, lengths, times) is played in the lab with three
scale factors, each an orbit quantity per lab quantity:

    k_L = length_orbit / length_lab,   k_T = time_orbit / time_lab,   k_M = mass_orbit / mass_lab

so velocity scales by k_L / k_T, acceleration by k_L / k_T², force by k_M k_L / k_T², torque
by k_M k_L² / k_T², inertia by k_M k_L², angular velocity by 1 / k_T, impulse by
k_M k_L / k_T and energy by k_M k_L² / k_T² (dynamic similarity: every dimensionless group
of the motion is the same in the lab and in orbit).

The ODS integrates in lab units. Substituting x = k_L x', t = k_T t' into the CW equations
and Euler's equations with gravity gradient (DESIGN.md, Eqs. 1-7) gives the same equations
in the primed (lab) variables with

    Omega' = k_T Omega,   a' = k_M F_lab / m,
    I alpha' + w' x I w' = 3 Omega'^2 c x I c + k_M k_L^2 tau_lab

i.e. the ODS keeps the virtual body's own m and I, turns at k_T Omega, and multiplies the
measured force by ``force_scale = k_M`` and the measured torque by
``torque_scale = k_M k_L²``. Initial states are given in orbit units and divided down.

**Contact.** A Hunt–Crossley contact F = k d (1 + c ḋ) between the mockups is physical:
the lab's material meets the lab's impact speed. Its restitution depends on the group c·v
(the impact speed times the damping), which is the orbit's only if the lab impact speed is
the orbit's, v_lab = v_orbit, i.e. ``k_L == k_T``. A law with contact (two or more
satellites, a damped material) and k_L != k_T is refused. The orbit-equivalent stiffness is
then k_M / k_T² times the lab's (:func:`orbit_equivalent_material`).

**The paper's law** (``law = "paper"``) keeps its two hand-set knobs instead:
``[orbit] force_scale`` and ``torque_scale`` multiply the measured wrench, and the body the
ODS integrates is the mockup itself (its mass and box inertia). Translation then goes as a
body of m / force_scale, rotation as one of I / torque_scale, which need not be one body;
:func:`describe` says which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.config import (
    PAPER_FORCE_SCALE,
    PAPER_TORQUE_SCALE,
    EmulatorConfig,
    SatelliteConfig,
)

__all__ = ["Scaling", "box_inertia", "describe", "mockup_mass_kg", "ods_inertia_kgm2",
           "orbit_equivalent_material", "scaling_of", "summary_line", "virtual_inertia_kgm2"]


@dataclass(frozen=True)
class Scaling:
    """The scaling in force: the three factors (orbit per lab) and what the ODS does with
    a measured wrench."""

    law: str
    length: float
    time: float
    mass: float
    force_scale: float
    """What the ODS multiplies a measured force by (k_M; the paper: its knob)."""
    torque_scale: float
    """What the ODS multiplies a measured torque by (k_M k_L²; the paper: its knob)."""

    @property
    def velocity(self) -> float:
        """Orbit velocity per lab velocity, k_L / k_T."""
        return self.length / self.time

    @property
    def impulse(self) -> float:
        """Orbit impulse per lab impulse, k_M k_L / k_T (momentum alike)."""
        return self.mass * self.length / self.time

    def orbit_rate_lab(self, orbit_rate_radps: float) -> float:
        """The orbit rate the lab sees, k_T Omega."""
        return self.time * orbit_rate_radps

    def ods_force(self, force_orbit_N):
        """The ODS input that applies an orbit force F_o to the virtual body:
        F_o k_T² / (k_L force_scale) (the ODS multiplies its input by force_scale and moves
        lengths in lab metres and times in lab seconds: a' = a k_T² / k_L)."""
        return np.asarray(force_orbit_N, float) * (self.time**2 / (self.length
                                                                   * self.force_scale))

    def ods_torque(self, torque_orbit_Nm):
        """The ODS input that applies an orbit torque τ_o: τ_o k_T² / torque_scale (angles
        are not scaled, so the angular acceleration is k_T² the orbit's; the inertia is
        the virtual body's own and the input is multiplied by torque_scale; under
        "similarity" torque_scale = k_M k_L², i.e. τ_o k_T² / (k_M k_L²), which is the
        orbit-per-lab torque factor k_M k_L² / k_T² inverted)."""
        return np.asarray(torque_orbit_Nm, float) * (self.time**2 / self.torque_scale)

    def to_lab(self, position_m, velocity_mps, omega_radps):
        """An orbit state (position, velocity, angular velocity) in lab units."""
        return (np.asarray(position_m, float) / self.length,
                np.asarray(velocity_mps, float) / self.velocity,
                np.asarray(omega_radps, float) * self.time)


def box_inertia(mass_kg: float, size_m) -> np.ndarray:
    """Principal moments of a uniform box: I_x = m (b^2 + c^2) / 12 and so on."""
    sx, sy, sz = size_m
    return mass_kg / 12.0 * np.array([sy**2 + sz**2, sx**2 + sz**2, sx**2 + sy**2])


def scaling_of(config: EmulatorConfig) -> Scaling:
    """The scaling a configuration asks for (validated with it: app/config/)."""
    s = config.scaling
    if s.law == "similarity":
        return Scaling("similarity", s.length, s.time, s.mass,
                       force_scale=s.mass, torque_scale=s.mass * s.length**2)
    orbit = config.orbit
    return Scaling("paper", 1.0, 1.0, 1.0,
                   force_scale=PAPER_FORCE_SCALE if orbit.force_scale is None
                   else orbit.force_scale,
                   torque_scale=PAPER_TORQUE_SCALE if orbit.torque_scale is None
                   else orbit.torque_scale)


def virtual_inertia_kgm2(sat: SatelliteConfig, scaling: Scaling) -> np.ndarray:
    """The virtual body's principal inertia (orbit units): as given, else a uniform box of
    its mass and the mockup's size scaled up by k_L."""
    if sat.inertia_kgm2 is not None:
        return np.array(sat.inertia_kgm2, dtype=float)
    return box_inertia(sat.mass_kg, scaling.length * np.asarray(sat.size_m, float))


def ods_inertia_kgm2(sat: SatelliteConfig, scaling: Scaling) -> np.ndarray:
    """The inertia the ODS integrates: the virtual body's under "similarity", the
    mockup's (given, or its box) under the paper's law."""
    if scaling.law == "similarity":
        return virtual_inertia_kgm2(sat, scaling)
    return sat.principal_inertia()


def orbit_equivalent_material(stiffness_Npm: float, damping_spm: float,
                              scaling: Scaling) -> tuple[float, float]:
    """The contact an emulated contact stands for in orbit: F_orbit = k_M k_L / k_T² F_lab
    at d_orbit = k_L d_lab and ḋ_orbit = (k_L / k_T) ḋ_lab gives the Hunt–Crossley
    stiffness k_M / k_T² k_lab and damping (k_T / k_L) c_lab."""
    return (scaling.mass / scaling.time**2 * stiffness_Npm,
            scaling.time / scaling.length * damping_spm)


def describe(config: EmulatorConfig) -> dict:
    """The scaling in force, for metrics.json, the summary and the plot titles: the
    factors, and for each satellite the virtual body, the mockup, and the lab-equivalent
    body the ODS moves under a measured wrench (mass m / force_scale, inertia
    I / torque_scale), with its inertia against a uniform box of that mass and the
    mockup's size: 1 for one consistent body."""
    sc = scaling_of(config)
    bodies = [describe_body(sat, config, sc) for sat in config.satellites]
    return {
        "law": sc.law,
        "length": sc.length, "time": sc.time, "mass": sc.mass,
        "force_scale": sc.force_scale, "torque_scale": sc.torque_scale,
        "satellites": bodies,
        "text": summary_line(config),
    }


def describe_body(sat: SatelliteConfig, config: EmulatorConfig, sc: Scaling) -> dict:
    """One satellite under the scaling: its virtual body, its mockup, and the lab-equivalent
    body (m / force_scale, I / torque_scale) with its inertia against a uniform box."""
    inertia = ods_inertia_kgm2(sat, sc)
    lab_mass = sat.mass_kg / sc.force_scale if sc.force_scale > 0 else float("inf")
    lab_inertia = inertia / sc.torque_scale if sc.torque_scale > 0 else None
    ratio = None
    if lab_inertia is not None and np.isfinite(lab_mass):
        ratio = float(np.mean(lab_inertia / box_inertia(lab_mass, sat.size_m)))
    return {
        "name": sat.name,
        "mass_kg": sat.mass_kg,
        "inertia_kgm2": [float(v) for v in inertia],
        "mockup_mass_kg": mockup_mass_kg(sat, config),
        "lab_equivalent_mass_kg": float(lab_mass),
        "lab_equivalent_inertia_kgm2": None if lab_inertia is None else
        [float(v) for v in lab_inertia],
        "inertia_vs_uniform_box": ratio,
    }


def mockup_mass_kg(sat: SatelliteConfig, config: EmulatorConfig) -> float:
    """The physical mockup's mass, which the sensor chain compensates: given, else (the
    paper's law) the satellite's own mass, the mockup being the body."""
    return sat.mockup_mass_kg if sat.mockup_mass_kg is not None else sat.mass_kg


def summary_line(config: EmulatorConfig) -> str:
    """One line for plot titles and the summary: the law, its factors, and what each
    satellite moves as (a body shared by several once: "chaser and target: each ...")."""
    sc = scaling_of(config)
    if sc.law == "similarity":
        parts = {}
        for sat in config.satellites:
            text = f"a {sat.mass_kg:g} kg satellite on a {mockup_mass_kg(sat, config):g} kg mockup"
            parts.setdefault(text, []).append(sat.name)
        return (f"scaling: similarity, orbit per lab: length x{sc.length:g}, time "
                f"x{sc.time:g}, mass x{sc.mass:g}; "
                + "; ".join(f"{' and '.join(names)}: {'each ' if len(names) > 1 else ''}{text}"
                            for text, names in parts.items()))
    parts = {}
    for sat in config.satellites:
        body = describe_body(sat, config, sc)
        ratio = body["inertia_vs_uniform_box"]
        text = (f"{body['lab_equivalent_mass_kg']:g} kg"
                + ("" if ratio is None else f" with {ratio:.4g}x a uniform box's inertia"))
        parts.setdefault(text, []).append(sat.name)
    return (f"scaling: the paper's knobs (force x{sc.force_scale:g}, torque "
            f"x{sc.torque_scale:g}); "
            + "; ".join(f"{' and '.join(names)} move{'s' if len(names) == 1 else ''} as {text}"
                        for text, names in parts.items()))
