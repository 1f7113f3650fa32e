"""Simulated UR10e joint position servo (DESIGN.md "The simulated UR10e").

Each control cycle the caller hands over one joint set-point. The servo

1. delays it by ``delay_cycles`` (transport delay: the controller acts on the set-point
   sent ``delay_cycles`` cycles earlier);
2. checks it like the real controller does and raises a *protective stop* if it would
   violate a limit: a joint beyond ``±position_limit_rad`` ("joint 2 position limit"), an
   implied speed ``(sp - previous sp) / dt`` beyond the joint's speed limit ("joint 3 speed
   limit"), or a TCP outside the safety box ("TCP left safety volume"); joints 1-based,
   checked in that order, first violation reported;
3. tracks the accepted set-point with a critically damped (by default) second-order
   response of ``bandwidth_hz``, saturated at the acceleration and speed limits
   (semi-implicit Euler, one step per cycle).

When stopped, the arm ignores set-points and *decelerates* to rest at the acceleration
limit (UR stop category 2 style: it stays on its path, joint by joint), then stays halted
until :meth:`UR10eServo.reset`.

:meth:`UR10eServo.step` runs through the compiled kernel of :mod:`app.sim.servo_kernel`
(``UR10eServo.use_kernel``, same results) when the safety box carries its kinematics
(:func:`safety_box_for_robot`, or no box); the Python methods below stay the reference.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.config import RobotConfig, ServoConfig
from app.sim.servo_kernel import reason_of, servo_step
from app.sim.ur10e import N_JOINTS, T_F_C_from_config, T_W_B_from_config, UR10e
from app.sim.ur10e_kernel import TcpChain, tcp_chain

__all__ = ["SafetyBox", "ServoState", "UR10eServo", "safety_box_for_robot"]


@dataclass(frozen=True)
class SafetyBox:
    """Axis-aligned box in the lab frame W that the TCP must stay in.

    ``tcp_position_W`` maps joint positions to the TCP position in W (the caller's
    kinematics and mounting), so the servo itself stays free of robot geometry.
    ``chain``, when given, is the same map for the compiled servo (UR10e kinematics).
    """

    p_min_W_m: np.ndarray
    p_max_W_m: np.ndarray
    tcp_position_W: Callable[[np.ndarray], np.ndarray]
    chain: TcpChain | None = None

    def contains(self, q_rad: np.ndarray) -> bool:
        p_W = self.tcp_position_W(q_rad)
        return bool(np.all(p_W >= self.p_min_W_m) and np.all(p_W <= self.p_max_W_m))


def safety_box_for_robot(robot: RobotConfig, ur: UR10e | None = None) -> SafetyBox:
    """The RobotConfig safety box, with the TCP from UR10e FK, ``T_W_B`` and ``T_F_C``."""
    ur = ur or UR10e()
    T_W_B = T_W_B_from_config(robot)
    T_F_C = T_F_C_from_config(robot)

    def tcp_position_W(q_rad: np.ndarray) -> np.ndarray:
        return (T_W_B @ ur.tcp_pose(q_rad, T_F_C))[:3, 3]

    return SafetyBox(
        np.array(robot.safety_box_min_m), np.array(robot.safety_box_max_m), tcp_position_W,
        chain=tcp_chain(ur.model, ur.flange_id, T_W_B, T_F_C),
    )


@dataclass
class ServoState:
    """Actual joint state of the arm and its stop status."""

    q_rad: np.ndarray
    qd_radps: np.ndarray
    qdd_radps2: np.ndarray
    stopped: bool = False
    reason: str = ""


_NO_BOX = np.zeros(3)
_NO_CHAIN = TcpChain(np.zeros((N_JOINTS, 3, 3)), np.zeros((N_JOINTS, 3)), np.eye(3),
                     np.zeros(3), np.eye(4), np.eye(4))


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
        w = 2.0 * math.pi * cfg.bandwidth_hz
        self._w2 = w * w
        self._2zw = 2.0 * cfg.damping_ratio * w
        self.use_kernel = True
        """Run step() through app.sim.servo_kernel (same results; needs a box with a chain)."""
        self.reset(q0_rad)

    # --- public -----------------------------------------------------------------------

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
        """Advance one cycle ``dt_s`` with a new set-point; returns the (live) state."""
        if self.use_kernel and (self.safety is None or self.safety.chain is not None):
            return self._step_compiled(np.asarray(q_setpoint_rad, dtype=float))
        sp = self._delay(np.array(q_setpoint_rad, dtype=float))
        if not self.state.stopped:
            reason = self.check(sp)
            if reason:
                self.state.stopped = True
                self.state.reason = reason
            else:
                self._sp_prev = sp
        if self.state.stopped:
            self._decelerate()
        else:
            self._track(sp)
        return self.state

    def _delay(self, sp: np.ndarray) -> np.ndarray:
        """Put a set-point into the delay ring; return the one sent delay_cycles ago."""
        if not len(self._ring):
            return sp
        out = self._ring[self._slot].copy()
        self._ring[self._slot] = sp
        self._slot = (self._slot + 1) % len(self._ring)
        return out

    def _step_compiled(self, sp: np.ndarray) -> ServoState:
        """:meth:`step` in one call of the compiled kernel (same state, same results)."""
        s, box, cfg = self.state, self.safety, self.cfg
        chain = _NO_CHAIN if box is None or box.chain is None else box.chain
        lo, hi = (_NO_BOX, _NO_BOX) if box is None else (box.p_min_W_m, box.p_max_W_m)
        slot = self._slot if len(self._ring) else -1
        q, qd, qdd = np.empty(N_JOINTS), np.empty(N_JOINTS), np.empty(N_JOINTS)
        code = servo_step(
            sp, self._ring, slot, self._sp_prev, s.q_rad, s.qd_radps, q, qd, qdd, s.stopped,
            self.dt_s, self._w2, self._2zw, self.accel_limit_radps2, cfg.position_limit_rad,
            self.speed_limits_radps, box is not None, lo, hi, *chain,
        )
        if slot >= 0:
            self._slot = (slot + 1) % len(self._ring)
        s.q_rad, s.qd_radps, s.qdd_radps2 = q, qd, qdd
        if code:
            s.stopped, s.reason = True, reason_of(code)
        return s

    def check(self, sp: np.ndarray) -> str:
        """Reason a set-point would trigger a protective stop, or ``""`` if it is fine."""
        lim = self.cfg.position_limit_rad
        for j in range(N_JOINTS):
            if not abs(sp[j]) <= lim:  # also catches NaN
                return f"joint {j + 1} position limit"
        speed = np.abs(sp - self._sp_prev) / self.dt_s
        for j in range(N_JOINTS):
            if speed[j] > self.speed_limits_radps[j] * (1.0 + 1e-9):
                return f"joint {j + 1} speed limit"
        if self.safety is not None and not self.safety.contains(sp):
            return "TCP left safety volume"
        return ""

    # --- dynamics -------------------------------------------------------------------------

    def _track(self, sp: np.ndarray) -> None:
        """Second-order tracking: ``qdd = w^2 (sp - q) - 2 zeta w qd``, then saturation."""
        s = self.state
        qdd = self._w2 * (sp - s.q_rad) - self._2zw * s.qd_radps
        self._integrate(qdd)

    def _decelerate(self) -> None:
        """Brake every joint to rest at the acceleration limit (no overshoot through zero)."""
        s = self.state
        qdd = -np.sign(s.qd_radps) * np.minimum(
            self.accel_limit_radps2, np.abs(s.qd_radps) / self.dt_s
        )
        self._integrate(qdd)

    def _integrate(self, qdd_cmd: np.ndarray) -> None:
        s, dt, a = self.state, self.dt_s, self.accel_limit_radps2
        qd_new = np.clip(s.qd_radps + dt * np.clip(qdd_cmd, -a, a), -self.speed_limits_radps,
                         self.speed_limits_radps)
        s.qdd_radps2 = (qd_new - s.qd_radps) / dt
        s.qd_radps = qd_new
        s.q_rad = s.q_rad + dt * qd_new
