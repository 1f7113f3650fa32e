"""Compiled (numba) servo cycle, same maths as UR10eServo's Python path.

One call does a whole :meth:`UR10eServo.step`: the transport-delay ring, the protective-stop
checks (position, speed, then the safety-box TCP through the compiled UR10e kinematics of
:mod:`app.sim.ur10e_kernel`), and the second-order tracking or the braking, saturated at
the acceleration and speed limits. The stop reason comes back as a code, see
:func:`reason_of`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.sim.ur10e_kernel import tcp_position_W

__all__ = ["BOX_CODE", "reason_of", "servo_step"]

N = 6
BOX_CODE = 2 * N + 1
"""Code of "TCP left safety volume"; 1..6: joint position limit, 7..12: joint speed limit."""


def reason_of(code: int) -> str:
    """The protective-stop reason of a :func:`servo_step` code (0: none)."""
    if code == 0:
        return ""
    if code <= N:
        return f"joint {code} position limit"
    if code <= 2 * N:
        return f"joint {code - N} speed limit"
    return "TCP left safety volume"


@njit(cache=True, fastmath=False)
def _check(sp, sp_prev, dt, pos_lim, speed_lim, use_box, box_min, box_max,
           pR, pp, fR, fp, T_W_B, T_F_C):
    """Code of the first limit a set-point violates (UR10eServo.check), 0 if none."""
    for j in range(N):
        if not abs(sp[j]) <= pos_lim:  # also catches NaN
            return j + 1
    for j in range(N):
        if abs(sp[j] - sp_prev[j]) / dt > speed_lim[j] * (1.0 + 1e-9):
            return N + j + 1
    if use_box:
        p = np.empty(3)
        tcp_position_W(sp, pR, pp, fR, fp, T_W_B, T_F_C, p)
        for a in range(3):
            if not (p[a] >= box_min[a] and p[a] <= box_max[a]):
                return BOX_CODE
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
    sp = np.empty(N)
    for j in range(N):
        sp[j] = sp_in[j]
    if slot >= 0:
        for j in range(N):
            sp[j], ring[slot, j] = ring[slot, j], sp[j]
    code = 0
    if not stopped:
        code = _check(sp, sp_prev, dt, pos_lim, speed_lim, use_box, box_min, box_max,
                      pR, pp, fR, fp, T_W_B, T_F_C)
        if code == 0:
            for j in range(N):
                sp_prev[j] = sp[j]
    halt = stopped or code != 0
    for j in range(N):
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
