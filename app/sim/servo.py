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
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.config import RobotConfig, ServoConfig
from app.sim.ur10e import N_JOINTS, T_F_C_from_config, T_W_B_from_config, UR10e

__all__ = ["SafetyBox", "ServoState", "UR10eServo", "safety_box_for_robot"]


@dataclass(frozen=True)
class SafetyBox:
    """Axis-aligned box in the lab frame W that the TCP must stay in.

    ``tcp_position_W`` maps joint positions to the TCP position in W (the caller's
    kinematics and mounting), so the servo itself stays free of robot geometry.
    """

    p_min_W_m: np.ndarray
    p_max_W_m: np.ndarray
    tcp_position_W: Callable[[np.ndarray], np.ndarray]

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
        np.array(robot.safety_box_min_m), np.array(robot.safety_box_max_m), tcp_position_W
    )


@dataclass
class ServoState:
    """Actual joint state of the arm and its stop status."""

    q_rad: np.ndarray
    qd_radps: np.ndarray
    qdd_radps2: np.ndarray
    stopped: bool = False
    reason: str = ""


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
        self.reset(q0_rad)

    # --- public -----------------------------------------------------------------------

    def reset(self, q_rad: np.ndarray | None = None) -> None:
        """Clear a protective stop; the arm rests at ``q_rad`` (default: where it is)."""
        q = self.state.q_rad if q_rad is None else np.array(q_rad, dtype=float)
        self.state = ServoState(q.copy(), np.zeros(N_JOINTS), np.zeros(N_JOINTS))
        self._queue = deque([q.copy() for _ in range(self.cfg.delay_cycles)])
        self._sp_prev = q.copy()  # last accepted set-point: the reference for speed checks

    @property
    def stopped(self) -> bool:
        return self.state.stopped

    @property
    def reason(self) -> str:
        return self.state.reason

    def step(self, q_setpoint_rad: np.ndarray) -> ServoState:
        """Advance one cycle ``dt_s`` with a new set-point; returns the (live) state."""
        sp = np.array(q_setpoint_rad, dtype=float)
        if self._queue:
            self._queue.append(sp)
            sp = self._queue.popleft()
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
