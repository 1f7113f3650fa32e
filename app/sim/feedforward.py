"""Servo feedforward: command the arm so that it follows the VFDM's set-points, not lags them.

Why: the lab drives its arm with a position servo whose tracking law it chose and knows,
``q̈ = k_p (sp − q) − k_d q̇`` (app/sim/servo.py :func:`tracking_gains`). UR's servoj is one:
``k_p = gain``, ``k_d = gain · lookahead_time``. At lookahead 0.03 s and gain 1200 its
natural frequency is 5.5 Hz at a damping ratio of 0.52: the arm is a ringing low-pass of
its set-points, not a delay. A lead (app/sim/compensation.py) makes up a delay, and over a
contact lasting a few of the arm's periods (the sponge collision's 118 ms, the rigid one's
24 ms) a low-pass is no delay: the mockup overshoots, rings, and the contact gains or loses
energy the satellites never had.

What: invert the law. For the arm to follow a desired joint trajectory ``q_d(t)`` exactly,
``q̈_d = k_p (sp − q_d) − k_d q̇_d``, so

    sp = q_d + (k_d / k_p) q̇_d + q̈_d / k_p                                        (FF)

(for servoj ``sp = q_d + lookahead · q̇_d + q̈_d / gain``). The tracking error ``e = q_d − q``
then obeys ``ë + k_d ė + k_p e = 0`` from rest: it stays zero. ``q_d`` is the VFDM's set-point
(where the lab wants the arm: the ODS's predicted pose through the VFDM), ``q̇_d`` and
``q̈_d`` its backward differences over the cycles the lab itself commanded; on a steady
ramp they are exact, so what is left for the lead is the transport delay and the VFDM's
own lag (the lag identification drives the same path). Everything here is the lab's own:
its commands and the gains it configured.

A set-point step is held within ``limit_fraction`` of the servo's speed limits (as the VFDM
holds its own, app/sim/vfdm.py :func:`limit_joint_step`): the controller would answer a
faster implied speed with a protective stop.
"""

from __future__ import annotations

import numpy as np

from app.config import EmulatorConfig
from app.sim.servo import tracking_gains

__all__ = ["ServoFeedforward", "servo_feedforward", "servo_feedforward_enabled"]


class ServoFeedforward:
    """Set-points that make a servo of tracking gains (k_p, k_d) follow ``q_d`` (Eq. FF)."""

    def __init__(self, k_p: float, k_d: float, dt_s: float, max_step_rad: np.ndarray,
                 q0_rad: np.ndarray) -> None:
        self.k_p, self.k_d, self.dt_s = float(k_p), float(k_d), float(dt_s)
        self.max_step_rad = np.asarray(max_step_rad, dtype=float)
        self.reset(q0_rad)

    def reset(self, q_rad: np.ndarray) -> None:
        """The arm at rest at ``q_rad``: no velocity, no acceleration in the history."""
        q = np.array(q_rad, dtype=float)
        self._q1, self._q2, self._sp = q.copy(), q.copy(), q.copy()

    def setpoint(self, q_d_rad: np.ndarray) -> np.ndarray:
        """The set-point of this cycle for the desired joints ``q_d_rad`` (Eq. FF, backward
        differences), its step from the last one held within ``max_step_rad``."""
        q_d = np.asarray(q_d_rad, dtype=float)
        dt = self.dt_s
        qd_d = (q_d - self._q1) / dt
        qdd_d = (q_d - 2.0 * self._q1 + self._q2) / (dt * dt)
        sp = q_d + (self.k_d / self.k_p) * qd_d + qdd_d / self.k_p
        sp = self._sp + np.clip(sp - self._sp, -self.max_step_rad, self.max_step_rad)
        self._q2, self._q1, self._sp = self._q1, q_d.copy(), sp
        return sp


def servo_feedforward_enabled(config: EmulatorConfig) -> bool:
    """``[compensation] servo_feedforward``, None meaning on with the servoj model; only
    with the compensation enabled."""
    comp = config.compensation
    if not comp.enabled:
        return False
    if comp.servo_feedforward is None:
        return config.servo.model == "servoj"
    return comp.servo_feedforward


def servo_feedforward(config: EmulatorConfig, q0_rad: np.ndarray) -> ServoFeedforward | None:
    """The feedforward of the configured servo, at rest at ``q0_rad`` (None when off)."""
    if not servo_feedforward_enabled(config):
        return None
    dt_s = 1.0 / config.loop.rate_hz
    k_p, k_d = tracking_gains(config.servo)
    max_step = (config.vfdm.limit_fraction * dt_s
                * np.array(config.servo.speed_limits_radps, dtype=float))
    return ServoFeedforward(k_p, k_d, dt_s, max_step, q0_rad)
