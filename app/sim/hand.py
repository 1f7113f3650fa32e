"""The operator's hand: scripted pulses, pushes and the gizmo (DESIGN.md "Scenarios").

Three ways a hand acts on a mockup:

* **scripted pulses** (``[[pulses]]`` of a scenario): a force in R and a torque in body
  axes, held constant over ``[start_s, end_s)``; the headless free-floating scenario;
* **pushes** (:class:`Push`, e.g. ``POST /api/push``): a force in R and a torque in body
  axes for a duration, from the cycle after it was posted, the force at a point of the
  body (its COM unless given);
* **the gizmo** (:class:`HandAnchor`): a fingertip that *presses* on the mockup at the
  point where it grabbed it (:func:`ray_box_hit`: where a click meets its box) and a grip
  that *twists* it, both unilateral: they push, they never pull (:class:`_Grip`).

The gizmo's contact law (:func:`unilateral`) is Hunt-Crossley's, the one the mockups'
surfaces follow (app/sim/contact.py): for a penetration d > 0 and its rate d_dot,

    F = min(F_max, max(0, k d (1 + c d_dot))),        F = 0 for d <= 0,

continuous in d and d_dot (zero at first touch, no jump), and never negative: when the
mockup runs ahead of the hand the contact opens and the hand lets go by itself. The
pressing direction n is the direction of the hand's first millimetre of travel (a finger
touches the grab point and presses that way); d is how far the hand has gone along n
since the grab, less how far the grab point has. The twist is the same law about the axis
of the gizmo's first turn, with the angles turned by the gizmo and by the body. A hand
held still after a drag therefore pushes the mockup until it has caught up with the
hand's position, then nothing: the satellite leaves at the speed it has (for a press
of depth d on an effective mass m: at most d sqrt(k / m)), never back.

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

from app.config import EmulatorConfig, HandConfig
from app.sim.rotations import matrix_to_rotvec, quat_to_matrix

__all__ = ["Command", "HandAnchor", "OperatorHand", "Push", "pulse_wrenches", "ray_box_hit",
           "unilateral"]

PRESS_LATCH_M = 1e-3
"""The hand's travel from where it grabbed that sets the pressing direction."""
TWIST_LATCH_RAD = 0.01
"""The gizmo's turn from where it grabbed that sets the twisting axis (0.6 degrees)."""


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
    at point_B_m (body axes, from the COM; the COM itself by default), and twisting it
    with torque_B_Nm (body axes, about the COM; none by default).

    Checked on creation: an index, three finite force and torque components and
    coordinates, a finite duration > 0.
    """

    satellite: int
    force_R_N: tuple[float, float, float]
    duration_s: float
    point_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_B_Nm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "satellite", _satellite_index(self.satellite))
        object.__setattr__(self, "force_R_N", _finite_vector3("force_R_N", self.force_R_N))
        object.__setattr__(self, "point_B_m", _finite_vector3("point_B_m", self.point_B_m))
        object.__setattr__(self, "torque_B_Nm",
                           _finite_vector3("torque_B_Nm", self.torque_B_Nm))
        d = self.duration_s
        if isinstance(d, bool) or not isinstance(d, int | float) or not (
                math.isfinite(d) and d > 0.0):
            raise ValueError(f"duration_s: must be a finite number of seconds > 0, got {d!r}")


@dataclass(frozen=True)
class HandAnchor:
    """The operator's hand (gizmo) at anchor_W_m, holding the mockup at point_B_m (body
    axes, from the COM: where the hand grabbed it), turned to attitude_W_wxyz (the
    gizmo's orientation in W; None: no twist); None lets go. The first anchor after a
    let-go (or at another point) is where the hand grabbed: it presses and twists from
    there (:class:`_Grip`).

    Checked on creation: an index, None or three finite coordinates, None or a finite
    non-zero quaternion.
    """

    satellite: int
    anchor_W_m: tuple[float, float, float] | None
    point_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    attitude_W_wxyz: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "satellite", _satellite_index(self.satellite))
        if self.anchor_W_m is not None:
            object.__setattr__(self, "anchor_W_m", _finite_vector3("anchor_W_m",
                                                                   self.anchor_W_m))
        object.__setattr__(self, "point_B_m", _finite_vector3("point_B_m", self.point_B_m))
        if self.attitude_W_wxyz is not None:
            q = self.attitude_W_wxyz
            try:
                q = tuple(float(x) for x in q)
            except (TypeError, ValueError):
                raise ValueError(f"attitude_W_wxyz: must be 4 numbers, got {q!r}") from None
            if len(q) != 4 or not all(math.isfinite(x) for x in q) or not any(q):
                raise ValueError(f"attitude_W_wxyz: must be 4 finite numbers, not all 0, "
                                 f"got {self.attitude_W_wxyz!r}")
            object.__setattr__(self, "attitude_W_wxyz", q)


Command = Push | HandAnchor


def unilateral(stiffness: float, damping: float, depth: float, rate: float,
               cap: float) -> float:
    """Hunt-Crossley's law of a contact that can only push: for a penetration ``depth``
    > 0 growing at ``rate``, min(cap, max(0, k d (1 + c d_dot))); 0 for d <= 0.
    Continuous in d and d_dot, never negative (it never pulls)."""
    if depth <= 0.0:
        return 0.0
    return min(cap, max(0.0, stiffness * depth * (1.0 + damping * rate)))


@dataclass
class _Grip:
    """The gizmo's hand on one mockup, from the grab to the let-go.

    It grabbed the mockup at point_B (body axes) with the gizmo at ``start_W`` turned to
    ``start_R``, the fingertip touching the grab point, which was at ``grab_W`` then (the
    grip's first evaluation). **Press**: once the hand has moved PRESS_LATCH_M from
    ``start_W``, that direction is ``normal_W`` for the rest of the grip; the penetration
    is d = ((A - start_W) - (P - grab_W)) · n for the hand at A and the grab point at P:
    how far the hand has pressed in since the grab less how far the point has given way.
    At the latch the press starts from the hand's travel then (k x 1 mm = 0.1 N at the
    default for a hand that moves smoothly; a gizmo that jumps further in one update
    starts from that). **Twist**: once the gizmo has turned TWIST_LATCH_RAD from
    ``start_R``, its axis is ``axis_W``; the penetration angle is the gizmo's turn about
    it since the grab less the body's (``body_turn_rad`` from its attitude ``grab_R`` at
    the grab, accumulated cycle to cycle so that whole turns count). The hand holds still
    between its updates, so the rates are the body's: d_dot = -v_P · n,
    a_dot = -omega · axis.
    """

    point_B: np.ndarray
    start_W: np.ndarray
    anchor_W: np.ndarray
    start_R: np.ndarray | None = None
    hand_R: np.ndarray | None = None
    normal_W: np.ndarray | None = None
    grab_W: np.ndarray | None = None
    axis_W: np.ndarray | None = None
    grab_R: np.ndarray | None = None
    body_turn_rad: float = 0.0
    body_R_seen: np.ndarray | None = None
    t_seen_s: float = -math.inf

    def aim(self, anchor: HandAnchor) -> None:
        """The hand moved (and turned) to where the gizmo now is."""
        self.anchor_W = np.array(anchor.anchor_W_m)
        if anchor.attitude_W_wxyz is not None:
            self.hand_R = quat_to_matrix(np.array(anchor.attitude_W_wxyz))
            if self.start_R is None:
                self.start_R = self.hand_R

    def hand_turn_W(self) -> np.ndarray:
        """The gizmo's turn since the grab, a rotation vector in W."""
        if self.hand_R is None or self.start_R is None:
            return np.zeros(3)
        return matrix_to_rotvec(self.hand_R @ self.start_R.T)

    def wrench_W(self, hand: HandConfig, t_s: float, p_W: np.ndarray, R_W: np.ndarray,
                 v_W: np.ndarray, w_W: np.ndarray) -> np.ndarray:
        """The grip's wrench on the body (force in W, moment about the COM), 6 values.

        The first evaluation at a new time (the cycle's actual state) latches the
        directions and accumulates the body's turn; further ones at the same time (an
        ideal cycle's sub-steps) only read them."""
        new_cycle = t_s > self.t_seen_s
        r_W = R_W @ self.point_B
        point_W = p_W + r_W
        wrench = np.zeros(6)
        if self.grab_W is None:
            self.grab_W, self.grab_R = point_W.copy(), R_W.copy()
        if self.normal_W is None and new_cycle:
            travel = self.anchor_W - self.start_W
            if np.linalg.norm(travel) >= PRESS_LATCH_M:
                self.normal_W = travel / np.linalg.norm(travel)
        if self.normal_W is not None:
            n = self.normal_W
            depth = float(((self.anchor_W - self.start_W) - (point_W - self.grab_W)) @ n)
            rate = -float((v_W + np.cross(w_W, r_W)) @ n)
            push = unilateral(hand.stiffness_Npm, hand.damping_spm, depth, rate,
                              hand.max_force_N)
            _add_force_at(wrench, push * n, r_W)
        turn_W = self.hand_turn_W()
        if self.axis_W is None and new_cycle and np.linalg.norm(turn_W) >= TWIST_LATCH_RAD:
            self.axis_W = turn_W / np.linalg.norm(turn_W)
            self.body_turn_rad, self.body_R_seen = 0.0, self.grab_R
        if self.axis_W is not None:
            axis = self.axis_W
            body = self.body_turn_rad + float(matrix_to_rotvec(R_W @ self.body_R_seen.T)
                                              @ axis)
            if new_cycle:
                self.body_turn_rad, self.body_R_seen = body, R_W.copy()
            angle = float(turn_W @ axis) - body
            twist = unilateral(hand.twist_stiffness_Nmprad, hand.twist_damping_sprad, angle,
                               -float(w_W @ axis), hand.max_torque_Nm)
            wrench[3:] += twist * axis
        self.t_seen_s = max(self.t_seen_s, t_s)
        return wrench



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
    """Every hand acting on the satellites: pulses, pushes and the gizmo's grips."""

    def __init__(self, config: EmulatorConfig, R_W_R: np.ndarray) -> None:
        self.config = config
        self.R_W_R = R_W_R
        self.n_sat = len(config.satellites)
        self._queue: list[Command] = []
        # (sat, force_R, until_s, point_B, torque_B)
        self._pushes: list[tuple[int, np.ndarray, float, np.ndarray, np.ndarray]] = []
        self._grips: dict[int, _Grip] = {}
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
        if not (self._queue or self._pushes):  # nothing queued, nothing pushing
            return
        for cmd in self._queue:
            if isinstance(cmd, Push):
                self._pushes.append((cmd.satellite, np.array(cmd.force_R_N),
                                     t_s + cmd.duration_s, np.array(cmd.point_B_m),
                                     np.array(cmd.torque_B_Nm)))
            else:
                self._move_grip(cmd)
        self._queue.clear()
        self._pushes = [p for p in self._pushes if t_s < p[2] - 1e-12]

    def _move_grip(self, anchor: HandAnchor) -> None:
        """Let go (None), grab (no grip yet, or at another point) or move the grip."""
        grip = self._grips.get(anchor.satellite)
        if anchor.anchor_W_m is None:
            self._grips.pop(anchor.satellite, None)
        elif grip is None or not np.array_equal(grip.point_B, anchor.point_B_m):
            grip = _Grip(point_B=np.array(anchor.point_B_m),
                         start_W=np.array(anchor.anchor_W_m),
                         anchor_W=np.array(anchor.anchor_W_m))
            grip.aim(anchor)
            self._grips[anchor.satellite] = grip
        else:
            grip.aim(anchor)

    def idle(self, t_s: float) -> bool:
        """No pulse, push or gizmo acts at t_s (the hand's wrenches are all zero)."""
        if self._pushes or self._grips:
            return False
        for start, end in self._pulse_windows:  # a loop: any() of a generator costs more
            if start <= t_s < end:
                return False
        return True

    def wrenches_W(self, t_s: float, p_W_C: np.ndarray, R_W_C: np.ndarray,
                   v_W: np.ndarray | None = None, w_W: np.ndarray | None = None,
                   ) -> np.ndarray:
        """(N, 6) wrenches in W about each COM (p_W_C (N, 3), R_W_C (N, 3, 3), v_W and
        w_W (N, 3) of the mockups; velocities zero if not given).

        Pulses act through the COM; pushes at their point, with the force and torque they
        specify (a hand that keeps its push steady); the gizmo's grip presses and twists
        unilaterally (:class:`_Grip`, :func:`unilateral`). A force F at r (from the COM,
        in W) adds the moment r × F.
        """
        wrench = np.zeros((self.n_sat, 6))
        if self.idle(t_s):
            return wrench
        force_R, torque_B = pulse_wrenches(self.config, t_s)
        wrench[:, :3] = force_R @ self.R_W_R.T
        for i in range(self.n_sat):
            wrench[i, 3:] = R_W_C[i] @ torque_B[i]
        for sat, f_R, _, point_B, torque_B in self._pushes:
            _add_force_at(wrench[sat], self.R_W_R @ f_R, R_W_C[sat] @ point_B)
            wrench[sat, 3:] += R_W_C[sat] @ torque_B
        still = np.zeros(3)
        for sat, grip in self._grips.items():
            wrench[sat] += grip.wrench_W(
                self.config.hand, t_s, p_W_C[sat], R_W_C[sat],
                still if v_W is None else v_W[sat], still if w_W is None else w_W[sat])
        return wrench


def _add_force_at(wrench_W: np.ndarray, force_W: np.ndarray, r_W: np.ndarray) -> None:
    """Add a force applied at r_W (from the COM) to a wrench about the COM."""
    wrench_W[:3] += force_W
    wrench_W[3:] += np.cross(r_W, force_W)
