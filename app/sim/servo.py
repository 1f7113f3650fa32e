"""Simulated UR10e joint position servo (DESIGN.md "The simulated UR10e"), compiled.

Each control cycle the caller hands over one joint set-point. The servo

1. delays it by ``delay_cycles`` (transport delay: the controller acts on the set-point
   sent ``delay_cycles`` cycles earlier);
2. checks it like the real controller does and raises a *protective stop* if it would
   violate a limit: a joint beyond ``±position_limit_rad`` ("joint 2 position limit"), an
   implied speed ``(sp − previous sp) / dt`` beyond the joint's speed limit (UR10e data
   sheet: 120 °/s base and shoulder, 180 °/s elbow and wrists; "joint 3 speed limit"), or
   a TCP outside the safety box ("TCP left safety volume"); joints 1-based, checked in
   that order, first violation reported;
3. tracks the accepted set-point with a critically damped (by default) second-order
   response of ``bandwidth_hz``, ``q̈ = ω² (sp − q) − 2ζω q̇``, or (``model = "servoj"``)
   as UR's servoj does, ``q̈ = gain (sp − q − lookahead q̇)`` (:func:`tracking_gains`),
   saturated at the acceleration and speed limits (semi-implicit Euler, one step per
   cycle).

When stopped, the arm ignores set-points and *decelerates* to rest at the acceleration
limit (UR stop category 2 style: it stays on its path, joint by joint), then stays halted
until :meth:`UR10eServo.reset`. One cycle is one call of the kernel :func:`servo_step`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from app.config import RobotConfig, ServoConfig
from app.sim.ur10e import (
    CHAIN_SIZE,
    N_JOINTS,
    T_F_C_from_config,
    T_W_B_from_config,
    TcpChain,
    chain_constants,
    chain_views,
    tcp_chain,
    tcp_position_W,
)

__all__ = ["N_SERVO_CONSTANTS", "SafetyBox", "ServoState", "UR10eServo", "reason_of",
           "safety_box_for_robot", "seconds_until_beyond", "seconds_until_outside",
           "servo_constants", "servo_step", "tracking_gains"]

BOX_CODE = 2 * N_JOINTS + 1
"""Stop code of "TCP left safety volume"; 1..6: joint position limit, 7..12: speed limit."""


def reason_of(code: int) -> str:
    """The protective-stop reason of a :func:`servo_step` code (0: none)."""
    if code == 0:
        return ""
    if code <= N_JOINTS:
        return f"joint {code} position limit"
    if code <= 2 * N_JOINTS:
        return f"joint {code - N_JOINTS} speed limit"
    return "TCP left safety volume"


@dataclass(frozen=True)
class SafetyBox:
    """Axis-aligned box in the lab frame W that the TCP of the arm ``chain`` must stay in."""

    p_min_W_m: np.ndarray
    p_max_W_m: np.ndarray
    chain: TcpChain

    def tcp_position_W(self, q_rad: np.ndarray) -> np.ndarray:
        """The TCP position in W at the joint positions q_rad."""
        out = np.empty(3)
        tcp_position_W(np.asarray(q_rad, dtype=float), *self.chain, out)
        return out

    def contains(self, q_rad: np.ndarray) -> bool:
        p_W = self.tcp_position_W(q_rad)
        return bool(np.all(p_W >= self.p_min_W_m) and np.all(p_W <= self.p_max_W_m))


def seconds_until_outside(p_W_m, v_W_mps, p_min_W_m, p_max_W_m) -> float:
    """When a point at p_W_m moving straight at v_W_mps leaves the box [p_min, p_max]:
    0 if it is outside already, inf if it never does (a satellite's course over a few
    seconds: the orbit bends it by ~Ω t, 1e-3 rad/s, so the straight line is its course)."""
    p, v = np.asarray(p_W_m, float), np.asarray(v_W_mps, float)
    lo, hi = np.asarray(p_min_W_m, float), np.asarray(p_max_W_m, float)
    if np.any(p < lo) or np.any(p > hi):
        return 0.0
    t = np.inf
    for a in range(3):
        if v[a] > 0.0:
            t = min(t, (hi[a] - p[a]) / v[a])
        elif v[a] < 0.0:
            t = min(t, (lo[a] - p[a]) / v[a])
    return float(t)


def seconds_until_beyond(p_W_m, v_W_mps, centre_W_m, radius_m: float) -> float:
    """When a point at p_W_m moving straight at v_W_mps gets farther than radius_m from
    centre_W_m (solves |p + v t - c| = r for its later root): 0 if it is already, inf if
    it never does."""
    d = np.asarray(p_W_m, float) - np.asarray(centre_W_m, float)
    v = np.asarray(v_W_mps, float)
    c = float(d @ d) - radius_m**2
    if c > 0.0:
        return 0.0
    a, b = float(v @ v), 2.0 * float(d @ v)
    if a == 0.0:
        return float("inf")
    return float((-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a))


def safety_box_for_robot(robot: RobotConfig) -> SafetyBox:
    """The RobotConfig safety box, for the TCP of the UR10e at ``T_W_B`` with ``T_F_C``."""
    chain = tcp_chain(T_W_B_from_config(robot), T_F_C_from_config(robot))
    return SafetyBox(np.array(robot.safety_box_min_m), np.array(robot.safety_box_max_m), chain)


@dataclass
class ServoState:
    """Actual joint state of the arm and its stop status."""

    q_rad: np.ndarray
    qd_radps: np.ndarray
    qdd_radps2: np.ndarray
    stopped: bool = False
    reason: str = ""


# --- kernels ------------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def _check(sp, sp_prev, dt, pos_lim, speed_lim, use_box, box_min, box_max,
           pR, pp, fR, fp, T_W_B, T_F_C):
    """Code of the first limit a set-point violates, 0 if none (step 2 of the module doc)."""
    n = 6
    for j in range(n):
        if not abs(sp[j]) <= pos_lim:  # also catches NaN
            return j + 1
    for j in range(n):
        if abs(sp[j] - sp_prev[j]) / dt > speed_lim[j] * (1.0 + 1e-9):
            return n + j + 1
    if use_box:
        p = np.empty(3)
        tcp_position_W(sp, pR, pp, fR, fp, T_W_B, T_F_C, p)
        for a in range(3):
            if not (p[a] >= box_min[a] and p[a] <= box_max[a]):
                return 2 * n + 1
    return 0


@njit(cache=True, fastmath=False)
def servo_step(sp_in, ring, slot, sp_prev, q, qd, q_new, qd_new, qdd_new, stopped,
               dt, w2, two_zw, accel, pos_lim, speed_lim,
               use_box, box_min, box_max, pR, pp, fR, fp, T_W_B, T_F_C):
    """One servo cycle; fills q_new, qd_new, qdd_new and returns a new stop's code (or 0).

    ring (d, 6) holds the delayed set-points; ``slot`` is the index of the oldest (it is
    handed out and replaced by sp_in), -1 without delay. sp_prev (the last accepted
    set-point) is updated in place; ``stopped``: the arm is already in a protective stop.
    """
    n = 6
    sp = np.empty(n)
    for j in range(n):
        sp[j] = sp_in[j]
    if slot >= 0:  # 1. transport delay
        for j in range(n):
            sp[j], ring[slot, j] = ring[slot, j], sp[j]
    code = 0
    if not stopped:  # 2. the controller's checks
        code = _check(sp, sp_prev, dt, pos_lim, speed_lim, use_box, box_min, box_max,
                      pR, pp, fR, fp, T_W_B, T_F_C)
        if code == 0:
            for j in range(n):
                sp_prev[j] = sp[j]
    halt = stopped or code != 0
    for j in range(n):  # 3. tracking (or braking), saturated
        if halt:  # brake at the acceleration limit, no overshoot through zero
            v = qd[j]
            sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
            a = min(accel, abs(v) / dt)
            qdd = -sign * a
        else:  # second-order tracking
            qdd = w2 * (sp[j] - q[j]) - two_zw * qd[j]
        if qdd < -accel:
            qdd = -accel
        elif qdd > accel:
            qdd = accel
        v = qd[j] + dt * qdd
        if v < -speed_lim[j]:
            v = -speed_lim[j]
        elif v > speed_lim[j]:
            v = speed_lim[j]
        qdd_new[j] = (v - qd[j]) / dt
        qd_new[j] = v
        q_new[j] = q[j] + dt * v
    return code


# --- the servo ----------------------------------------------------------------------------


def tracking_gains(cfg: ServoConfig) -> tuple[float, float]:
    """(k_p, k_d) of the tracking law q̈ = k_p (sp − q) − k_d q̇ for the configured model.

    "second-order": k_p = ω², k_d = 2ζω with ω = 2π·bandwidth_hz.

    "servoj" (UR script manual, servoj: "the gain parameter works the same way as the
    P-term of a PID controller ... lookahead_time is used to project the current position
    forward in time with the current velocity"): q̈ = gain·(sp − (q + T_la q̇)), so k_p =
    gain and k_d = gain·T_la. Its natural frequency is √gain (34.6 rad/s at 1200), its
    damping ratio T_la·√gain / 2 (0.52 at 0.03 s and 1200: a step overshoots, as the manual
    warns a short lookahead does), and on a ramp it trails by exactly T_la (at rest in the
    ramp's frame q̈ = 0, so sp − q = T_la q̇): with the 2-3 cycles of the link, the 34 ms
    a UR10e shows at 0.03 s (Universal_Robots_Client_Library issue #86).
    """
    if cfg.model == "servoj":
        gain = cfg.servoj_gain
        return gain, gain * cfg.servoj_lookahead_s
    w = 2.0 * math.pi * cfg.bandwidth_hz
    return w * w, 2.0 * cfg.damping_ratio * w


_NO_BOX = np.zeros(3)
_NO_CHAIN = tcp_chain()


class UR10eServo:
    """Position servo with transport delay, second-order tracking, limits and safety stop."""

    def __init__(
        self,
        cfg: ServoConfig,
        dt_s: float,
        q0_rad: np.ndarray,
        safety: SafetyBox | None = None,
    ) -> None:
        self.cfg = cfg
        self.dt_s = float(dt_s)
        self.safety = safety
        self.speed_limits_radps = np.array(cfg.speed_limits_radps)
        self.accel_limit_radps2 = cfg.accel_limit_radps2
        self._w2, self._2zw = tracking_gains(cfg)
        self.reset(q0_rad)

    def reset(self, q_rad: np.ndarray | None = None) -> None:
        """Clear a protective stop; the arm rests at ``q_rad`` (default: where it is)."""
        q = self.state.q_rad if q_rad is None else np.array(q_rad, dtype=float)
        self.state = ServoState(q.copy(), np.zeros(N_JOINTS), np.zeros(N_JOINTS))
        # transport delay: ring of the set-points in flight, _slot indexes the oldest
        self._ring = np.tile(q, (self.cfg.delay_cycles, 1))
        self._slot = 0
        self._sp_prev = q.copy()  # last accepted set-point: the reference for speed checks

    @property
    def stopped(self) -> bool:
        return self.state.stopped

    @property
    def reason(self) -> str:
        return self.state.reason

    def step(self, q_setpoint_rad: np.ndarray) -> ServoState:
        """Advance one cycle ``dt_s`` with a new set-point; returns the (live) state.

        The state's q, q̇, q̈ are new arrays after every step (the old ones are never
        written), so a caller may keep them as a snapshot, or key a cache on them.
        """
        s, box, cfg = self.state, self.safety, self.cfg
        chain = _NO_CHAIN if box is None else box.chain
        lo, hi = (_NO_BOX, _NO_BOX) if box is None else (box.p_min_W_m, box.p_max_W_m)
        slot = self.delay_slot
        q, qd, qdd = np.empty(N_JOINTS), np.empty(N_JOINTS), np.empty(N_JOINTS)
        code = servo_step(
            np.asarray(q_setpoint_rad, dtype=float), self._ring, slot, self._sp_prev,
            s.q_rad, s.qd_radps, q, qd, qdd, s.stopped, self.dt_s, self._w2, self._2zw,
            self.accel_limit_radps2, cfg.position_limit_rad, self.speed_limits_radps,
            box is not None, lo, hi, *chain,
        )
        return self.commit(slot, q, qd, qdd, code)

    @property
    def delay_slot(self) -> int:
        """The transport delay ring's oldest row, which this step hands out (-1: no delay)."""
        return self._slot if len(self._ring) else -1

    def commit(self, slot: int, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
               code: int) -> ServoState:
        """Take a step that :func:`servo_step` made (here or inside a fused kernel,
        app/sim/arm_command.py) from ring row ``slot``: the new joint state (new arrays),
        the stop its code names; returns the state."""
        s = self.state
        if slot >= 0:
            self._slot = (slot + 1) % len(self._ring)
        s.q_rad, s.qd_radps, s.qdd_radps2 = q, qd, qdd
        if code:
            s.stopped, s.reason = True, reason_of(code)
        return s

    def constants(self) -> np.ndarray:
        """(N_SERVO_CONSTANTS,) what :func:`servo_step` reads and never writes, in one
        buffer (:func:`servo_constants`): dt, the tracking gains, the acceleration and
        position limits, whether there is a safety box, its corners, the speed limits, the
        box's TCP chain (pR, pp, fR, fp, T_W_B, T_F_C). A snapshot: a box that moves (a
        rail's) needs :meth:`step`."""
        box = self.safety
        chain = _NO_CHAIN if box is None else box.chain
        lo, hi = (_NO_BOX, _NO_BOX) if box is None else (box.p_min_W_m, box.p_max_W_m)
        c = np.concatenate([
            [self.dt_s, self._w2, self._2zw, self.accel_limit_radps2,
             self.cfg.position_limit_rad, float(box is not None)],
            lo, hi, self.speed_limits_radps, chain_constants(chain)]).astype(float)
        assert c.shape == (N_SERVO_CONSTANTS,)
        return c


N_SERVO_CONSTANTS = 134
"""Length of :meth:`UR10eServo.constants`: 6 scalars, the box (3 + 3), the speed limits
(6), the chain (54 + 18 + 9 + 3 + 16 + 16)."""


@njit(cache=True, fastmath=False, inline="always")
def servo_constants(c):
    """The arguments of :func:`servo_step` after ``stopped`` from a
    :meth:`UR10eServo.constants` buffer: (dt, w2, two_zw, accel, pos_lim, speed_lim,
    use_box, box_min, box_max, pR, pp, fR, fp, T_W_B, T_F_C)."""
    return (c[0], c[1], c[2], c[3], c[4], c[12:18], c[5] > 0.5, c[6:9],
            c[9:12]) + chain_views(c[18:18 + CHAIN_SIZE])
