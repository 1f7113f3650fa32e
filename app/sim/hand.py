"""The operator's hand: scripted pulses, pushes and the gizmo (DESIGN.md "Scenarios").

Three ways a hand acts on a mockup:

* **scripted pulses** (``[[pulses]]`` of a scenario): a force in R and a torque in body
  axes, held constant over ``[start_s, end_s)``; the headless free-floating scenario;
* **pushes** (:class:`Push`, e.g. ``POST /api/push``): a force in R for a duration, from the
  cycle after it was posted, at a point of the body (its COM unless given);
* **the gizmo** (:class:`HandAnchor`): the hand is a spring from an anchor in the lab to the
  point where it grabbed the mockup (:func:`ray_box_hit`: where a click meets its box),
  saturated at the hand's maximum force.

A force at a point r of the body (from its COM) also turns it: the moment about the COM is
r × F. That is the wrench the mockup feels; the F/T sensor measures it, and the ODS applies
its force and moment scaled (``[orbit] force_scale``, ``torque_scale``).

Everything outside the loop posts commands; the hand consumes them at the start of the next
cycle, so the loop stays the only owner of its state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.config import EmulatorConfig

__all__ = ["Command", "HandAnchor", "OperatorHand", "Push", "pulse_wrenches", "ray_box_hit"]


def _satellite_index(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"satellite: must be an index >= 0, got {value!r}")
    return int(value)


def _finite_vector3(name: str, value) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be 3 numbers, got {value!r}") from None
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise ValueError(f"{name}: must be 3 finite numbers, got {value!r}")
    return v


@dataclass(frozen=True)
class Push:
    """A hand pushing satellite `satellite` (0-based) with force_R_N (in R) for duration_s,
    at point_B_m (body axes, from the COM; the COM itself by default).

    Checked on creation: an index, three finite force components and coordinates, a finite
    duration > 0.
    """

    satellite: int
    force_R_N: tuple[float, float, float]
    duration_s: float
    point_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "satellite", _satellite_index(self.satellite))
        object.__setattr__(self, "force_R_N", _finite_vector3("force_R_N", self.force_R_N))
        object.__setattr__(self, "point_B_m", _finite_vector3("point_B_m", self.point_B_m))
        d = self.duration_s
        if isinstance(d, bool) or not isinstance(d, int | float) or not (
                math.isfinite(d) and d > 0.0):
            raise ValueError(f"duration_s: must be a finite number of seconds > 0, got {d!r}")


@dataclass(frozen=True)
class HandAnchor:
    """The operator's hand (gizmo) at anchor_W_m, spring-coupled to the mockup at point_B_m
    (body axes, from the COM: where the hand grabbed it); None lets go.

    Checked on creation: an index, and None or three finite coordinates.
    """

    satellite: int
    anchor_W_m: tuple[float, float, float] | None
    point_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "satellite", _satellite_index(self.satellite))
        if self.anchor_W_m is not None:
            object.__setattr__(self, "anchor_W_m", _finite_vector3("anchor_W_m",
                                                                   self.anchor_W_m))
        object.__setattr__(self, "point_B_m", _finite_vector3("point_B_m", self.point_B_m))


Command = Push | HandAnchor


def ray_box_hit(origin_W: np.ndarray, direction_W: np.ndarray, T_W_C: np.ndarray,
                size_m) -> np.ndarray | None:
    """Where a ray (a click in the 3D view) first meets a box centred on its COM, in body
    axes from the COM; None if it misses (the slab method, in the box's frame)."""
    R, p = T_W_C[:3, :3], T_W_C[:3, 3]
    o = R.T @ (np.asarray(origin_W, float) - p)
    d = R.T @ np.asarray(direction_W, float)
    half = 0.5 * np.asarray(size_m, float)
    t_near, t_far = -np.inf, np.inf
    for k in range(3):
        if abs(d[k]) < 1e-12:
            if abs(o[k]) > half[k]:
                return None
            continue
        t0, t1 = sorted(((-half[k] - o[k]) / d[k], (half[k] - o[k]) / d[k]))
        t_near, t_far = max(t_near, t0), min(t_far, t1)
    if t_near > t_far or t_far < 0.0:
        return None
    return o + max(t_near, 0.0) * d


def pulse_wrenches(config: EmulatorConfig, t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Force (in R) and torque (body axes) of the scripted pulses active at t_s, (N, 3) each."""
    n = len(config.satellites)
    force, torque = np.zeros((n, 3)), np.zeros((n, 3))
    for p in config.pulses:
        if p.start_s <= t_s < p.end_s:
            i = config.satellite_index(p.satellite)
            force[i] += p.force_N
            torque[i] += p.torque_Nm
    return force, torque


class OperatorHand:
    """Every hand acting on the satellites: pulses, pushes and gizmo anchors."""

    def __init__(self, config: EmulatorConfig, R_W_R: np.ndarray) -> None:
        self.config = config
        self.R_W_R = R_W_R
        self.n_sat = len(config.satellites)
        self._queue: list[Command] = []
        # (sat, force_R, until_s, point_B)
        self._pushes: list[tuple[int, np.ndarray, float, np.ndarray]] = []
        self._anchors: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # sat -> anchor, point_B
        self._pulse_windows = [(p.start_s, p.end_s) for p in config.pulses]

    def post(self, command: Command) -> None:
        """Queue a command; it takes effect at the next :meth:`update`."""
        if not isinstance(command, Push | HandAnchor):
            raise TypeError(f"not a Push or HandAnchor: {command!r}")
        if not 0 <= command.satellite < self.n_sat:
            raise ValueError(
                f"satellite must be between 1 and {self.n_sat}, got {command.satellite + 1}"
            )
        self._queue.append(command)

    def update(self, t_s: float) -> None:
        """Apply the queued commands at t_s and let go of the pushes that have ended."""
        for cmd in self._queue:
            if isinstance(cmd, Push):
                self._pushes.append((cmd.satellite, np.array(cmd.force_R_N),
                                     t_s + cmd.duration_s, np.array(cmd.point_B_m)))
            elif cmd.anchor_W_m is None:
                self._anchors.pop(cmd.satellite, None)
            else:
                self._anchors[cmd.satellite] = (np.array(cmd.anchor_W_m),
                                                np.array(cmd.point_B_m))
        self._queue.clear()
        self._pushes = [p for p in self._pushes if t_s < p[2] - 1e-12]

    def idle(self, t_s: float) -> bool:
        """No pulse, push or gizmo acts at t_s (the hand's wrenches are all zero)."""
        return not (self._pushes or self._anchors
                    or any(start <= t_s < end for start, end in self._pulse_windows))

    def wrenches_W(self, t_s: float, p_W_C: np.ndarray, R_W_C: np.ndarray) -> np.ndarray:
        """(N, 6) wrenches in W about each COM (p_W_C (N, 3), R_W_C (N, 3, 3) of the mockups).

        Pulses act through the COM; pushes at their point, with the force they specify (a
        hand that keeps its push steady); the gizmo's hand is a spring from its anchor to
        the point it grabbed. A force F at r (from the COM, in W) adds the moment r × F.
        """
        wrench = np.zeros((self.n_sat, 6))
        if self.idle(t_s):
            return wrench
        force_R, torque_B = pulse_wrenches(self.config, t_s)
        wrench[:, :3] = force_R @ self.R_W_R.T
        for i in range(self.n_sat):
            wrench[i, 3:] = R_W_C[i] @ torque_B[i]
        for sat, f_R, _, point_B in self._pushes:
            _add_force_at(wrench[sat], self.R_W_R @ f_R, R_W_C[sat] @ point_B)
        hand = self.config.hand
        for sat, (anchor, point_B) in self._anchors.items():
            r_W = R_W_C[sat] @ point_B
            f = hand.stiffness_Npm * (anchor - (p_W_C[sat] + r_W))
            norm = float(np.linalg.norm(f))
            if norm > hand.max_force_N:
                f *= hand.max_force_N / norm
            _add_force_at(wrench[sat], f, r_W)
        return wrench


def _add_force_at(wrench_W: np.ndarray, force_W: np.ndarray, r_W: np.ndarray) -> None:
    """Add a force applied at r_W (from the COM) to a wrench about the COM."""
    wrench_W[:3] += force_W
    wrench_W[3:] += np.cross(r_W, force_W)
