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

What is left (Eq. FC): at the cycle a set-point is computed, ``q̈_d`` is known only up to
the last cycle (a backward difference), and the set-point reaches the arm a transport
delay later. Where the desired acceleration changes (a contact's onset), the arm is thus
sent last cycle's acceleration, and the velocity error ``dt · Δq̈_d`` stays in the arm:
servoj's own loop (5.5 Hz, damping 0.52) takes a period to work it off, which over a
contact of a period or less is a systematic error (the sponge collision on servoj: −7.6 %
of restitution with Eq. FF alone; the 50 Hz default servo's stiff loop absorbs it). So the
lab closes its own loop on the joints the arm reports (RTDE's ``actual_q``, ``actual_qd``):
it carries them through the set-points still in flight with the law it knows (its own
commands, its gains, the arm's acceleration and speed limits) to ``q̂, q̂̇`` at the cycle
its new set-point takes effect, and asks for the acceleration

    a = q̈_d + ω_c² (q_d − q̂) + 2 ω_c (q̇_d − q̂̇)                                 (FC)
    sp = q̂ + (a + k_d q̂̇) / k_p

(critically damped, ``ω_c = 2π · [compensation] servo_correction_hz``). When the arm is on
its track (``q̂ = q_d``, ``q̂̇ = q̇_d``) this is Eq. FF; off it, the error decays at ``ω_c``
instead of servoj's 5.5 Hz. ``servo_correction_hz = 0`` sends Eq. FF alone, and so does an
arm whose own loop is faster than ``ω_c`` (``√k_p > ω_c``: the default servo's 50 Hz).

A set-point step is held within ``limit_fraction`` of the servo's speed limits (as the VFDM
holds its own, app/sim/vfdm.py :func:`limit_joint_step`): the controller would answer a
faster implied speed with a protective stop.
"""

from __future__ import annotations

import numpy as np

from app.config import EmulatorConfig
from app.sim.servo import tracking_gains

__all__ = ["ServoFeedforward", "send", "servo_feedforward", "servo_feedforward_enabled"]


class ServoFeedforward:
    """Set-points that make a servo of tracking gains (k_p, k_d) follow ``q_d``: Eq. FF, and
    with ``correction_radps`` > 0 Eq. FC on the arm's reported joints. ``delay_cycles``,
    ``accel_limit_radps2`` and ``speed_limits_radps``: the servo's transport delay and
    limits, through which the reported joints are carried to the cycle a set-point acts."""

    def __init__(self, k_p: float, k_d: float, dt_s: float, max_step_rad: np.ndarray,
                 q0_rad: np.ndarray, correction_radps: float = 0.0, delay_cycles: int = 0,
                 accel_limit_radps2: float = np.inf,
                 speed_limits_radps: np.ndarray | None = None) -> None:
        self.k_p, self.k_d, self.dt_s = float(k_p), float(k_d), float(dt_s)
        self.max_step_rad = np.asarray(max_step_rad, dtype=float)
        self.correction_radps = float(correction_radps)
        self.delay_cycles = int(delay_cycles)
        self.accel_limit_radps2 = float(accel_limit_radps2)
        self.speed_limits_radps = (np.full(len(self.max_step_rad), np.inf)
                                   if speed_limits_radps is None
                                   else np.asarray(speed_limits_radps, dtype=float))
        self.reset(q0_rad)

    @property
    def corrects(self) -> bool:
        """Eq. FC only for an arm whose own loop is slower than the correction (servoj at
        gain 1200: 5.5 Hz); a stiffer servo (the default's 50 Hz) works its error off
        faster by itself, and Eq. FC would replace its loop with a slower one."""
        return self.correction_radps > np.sqrt(self.k_p)

    def reset(self, q_rad: np.ndarray) -> None:
        """The arm at rest at ``q_rad``: no velocity, no acceleration in the history, the
        set-points in flight all ``q_rad`` (as the servo's own delay line after its reset)."""
        q = np.array(q_rad, dtype=float)
        self._q1, self._q2, self._sp = q.copy(), q.copy(), q.copy()
        self._in_flight = [q.copy() for _ in range(self.delay_cycles)]

    def setpoint(self, q_d_rad: np.ndarray, q_rad: np.ndarray | None = None,
                 qd_radps: np.ndarray | None = None) -> np.ndarray:
        """The set-point of this cycle for the desired joints ``q_d_rad`` (backward
        differences): Eq. FC on the arm's reported joints ``q_rad``, ``qd_radps`` (after the
        last servo step) when the correction is on and they are given, else Eq. FF; its
        step from the last one held within ``max_step_rad``."""
        q_d = np.asarray(q_d_rad, dtype=float)
        dt = self.dt_s
        qd_d = (q_d - self._q1) / dt
        qdd_d = (q_d - 2.0 * self._q1 + self._q2) / (dt * dt)
        if self.corrects and q_rad is not None and qd_radps is not None:
            q_hat, qd_hat = self._carried(q_rad, qd_radps)
            w = self.correction_radps
            a = qdd_d + w * w * (q_d - q_hat) + 2.0 * w * (qd_d - qd_hat)  # Eq. FC
            sp = q_hat + (a + self.k_d * qd_hat) / self.k_p
        else:
            sp = q_d + (self.k_d / self.k_p) * qd_d + qdd_d / self.k_p  # Eq. FF
        sp = self._sp + np.clip(sp - self._sp, -self.max_step_rad, self.max_step_rad)
        self._q2, self._q1, self._sp = self._q1, q_d.copy(), sp
        if self._in_flight:
            self._in_flight.pop(0)
            self._in_flight.append(sp.copy())
        return sp

    def _carried(self, q_rad: np.ndarray, qd_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reported joints carried through the set-points in flight by the servo's law
        (app/sim/servo.py :func:`servo_step`'s tracking, with its limits)."""
        q = np.array(q_rad, dtype=float)
        v = np.array(qd_radps, dtype=float)
        lim_a, lim_v, dt = self.accel_limit_radps2, self.speed_limits_radps, self.dt_s
        for sp in self._in_flight:
            a = np.clip(self.k_p * (sp - q) - self.k_d * v, -lim_a, lim_a)
            v = np.clip(v + dt * a, -lim_v, lim_v)
            q = q + dt * v
        return q, v


def send(servo, feedforward: ServoFeedforward | None, q_d_rad: np.ndarray):
    """One step of ``servo`` (app/sim/servo.py UR10eServo) toward the desired joints
    ``q_d_rad``: as they are, or through ``feedforward`` on the joints the servo reports
    before the step. Returns the servo's state."""
    if feedforward is None:
        return servo.step(q_d_rad)
    st = servo.state
    return servo.step(feedforward.setpoint(q_d_rad, st.q_rad, st.qd_radps))


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
    speed = np.array(config.servo.speed_limits_radps, dtype=float)
    max_step = config.vfdm.limit_fraction * dt_s * speed
    return ServoFeedforward(k_p, k_d, dt_s, max_step, q0_rad,
                            2.0 * np.pi * config.compensation.servo_correction_hz,
                            config.servo.delay_cycles, config.servo.accel_limit_radps2, speed)
