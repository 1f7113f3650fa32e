"""One arm's command path as one compiled call: VFDM set-points, one servo step, the new FK.

Per cycle a fixed arm (app/sim/rig.py :meth:`ArmRig.command`) turns the target pose of its
mockup into joint motion in two stages, each its own compiled kernel called from Python:

1. :meth:`app.sim.vfdm.Vfdm.solve` — the target feedforward, the ``iterations`` internal
   VFDM steps (paper Eqs. 9-13) and the joint-step limits (:func:`vfdm_cycle`);
2. :meth:`app.sim.servo.UR10eServo.step` — the transport delay, the controller's checks
   and the second-order tracking (:func:`servo_step`);
3. and, at the next cycle's start, :meth:`ArmRig.mockup_state_W` — the forward kinematics
   of the new joint state: flange and mockup poses, the mockup's twist
   (:func:`mockup_state`).

:func:`arm_command` runs the three in one call, on the objects' own buffers: the VFDM's
constants and state (``Vfdm.constants``, its state buffer), the servo's constants
(``UR10eServo.constants()``, built once per rig), its delay ring and last accepted
set-point, the rig's TCP chain. Each stage is the very kernel the objects call
themselves, with the same inputs, so the result is the same to the last bit; what it
saves is the Python between them and the unpacking of some seventy arguments (a numba
call costs about 40 ns per array argument, measured here).

Not fused: the servo feedforward (app/sim/feedforward.py, NumPy), and a rail's chain
(app/sim/rail_rig.py), whose safety box moves with the carriage; their rigs take the two
calls.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.sim.frames import satellite_pose
from app.sim.servo import UR10eServo, servo_constants, servo_step
from app.sim.ur10e import TcpChain, chain_constants, chain_views, mockup_state
from app.sim.vfdm import Vfdm, vfdm_constants, vfdm_cycle_packed

__all__ = ["ArmCommand", "arm_command", "arm_command_towards"]

OUT_SIZE = 62
"""arm_command's out: the servo's new q, q̇, q̈ (18), the VFDM's last pose error (6), the
forward kinematics of the new joint state: T_W_F (16), T_W_C (16), v_W (3), ω_W (3)."""


@njit(cache=True, fastmath=False, inline="always")
def command_cycle(T, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q, qd, stopped,
                  out):
    """One cycle of a fixed arm's command path; returns (VFDM step scale, servo stop code).

    With ``[vfdm] sync_to_measured`` the virtual arm first takes the measured joints q;
    then :func:`vfdm_cycle_packed` towards the target T (4, 4) in the base frame (Eqs.
    9-13, the joint-step limits) on the VFDM's constants vfdm_c and state vfdm_x; its
    joints are the set-point of one :func:`servo_step` (delay ring row ``slot``, last
    accepted set-point sp_prev, joint state q, qd, ``stopped``) on the servo's constants
    servo_c; then :func:`mockup_state` of the new joint state on the rig's chain chain_c.
    out (:data:`OUT_SIZE`) := the servo's new q, q̇, q̈, the VFDM's last clamped pose
    error, the new T_W_F, T_W_C, v_W, ω_W.
    """
    sync = vfdm_constants(vfdm_c)[22]
    q_v = vfdm_x[0:6]
    if sync:
        for j in range(6):
            q_v[j] = q[j]
    scale = vfdm_cycle_packed(T, vfdm_c, vfdm_x, out[18:24])
    (dt, w2, two_zw, accel, pos_lim, speed_lim, use_box, box_min, box_max,
     pR, pp, fR, fp, T_W_B, T_F_C) = servo_constants(servo_c)
    code = servo_step(q_v, ring, slot, sp_prev, q, qd, out[0:6], out[6:12], out[12:18],
                      stopped, dt, w2, two_zw, accel, pos_lim, speed_lim, use_box, box_min,
                      box_max, pR, pp, fR, fp, T_W_B, T_F_C)
    pR, pp, fR, fp, T_W_B, T_F_C = chain_views(chain_c)
    mockup_state(out[0:6], out[6:12], pR, pp, fR, fp, T_W_B, T_F_C,
                 out[24:40].reshape((4, 4)), out[40:56].reshape((4, 4)), out[56:59],
                 out[59:62])
    return scale, code


@njit(cache=True, fastmath=False)
def arm_command(T, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q, qd, stopped,
                out):
    """:func:`command_cycle` towards the target T (4, 4) in the base frame."""
    return command_cycle(T, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q, qd,
                         stopped, out)


@njit(cache=True, fastmath=False)
def arm_command_towards(T_B_R, y, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot,
                        sp_prev, q, qd, stopped, out):
    """:func:`command_cycle` towards satellite ``satellite`` of the ODS state y (N, 13):
    the TCP target ``T_B_C* = T_B_R · T_R_sat`` (:func:`satellite_pose`, as
    ``ArmRig.tcp_target_B``)."""
    T = np.empty((4, 4))
    satellite_pose(T_B_R, y, satellite, T)
    return command_cycle(T, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q, qd,
                         stopped, out)


class ArmCommand:
    """The fused command path of one VFDM, one servo and the TCP chain of the arm they
    drive (a fixed arm: its safety box and its chain stand still, so the servo's and the
    chain's constants are read once, here)."""

    def __init__(self, vfdm: Vfdm, servo: UR10eServo, chain: TcpChain) -> None:
        self.vfdm, self.servo, self.chain = vfdm, servo, chain
        self.servo_constants = servo.constants()
        self.chain_constants = chain_constants(chain)

    def __call__(self, T_B_C_target: np.ndarray) -> tuple:
        """:meth:`Vfdm.solve` towards the target, :meth:`UR10eServo.step` to its
        set-point, in one compiled call; both objects end as after those two calls.
        Returns the forward kinematics of the new joint state, (T_W_F, T_W_C, v_W, ω_W),
        as :func:`mockup_state` gives it."""
        return self._cycle(arm_command, np.ascontiguousarray(T_B_C_target, dtype=float))

    def _cycle(self, kernel, *target) -> tuple:
        vfdm, servo = self.vfdm, self.servo
        st, slot, out = servo.state, servo.delay_slot, np.empty(OUT_SIZE)
        vfdm.last_scale, code = kernel(
            *target, vfdm.constants, vfdm._x, self.servo_constants, self.chain_constants,
            servo._ring, slot, servo._sp_prev, st.q_rad, st.qd_radps, st.stopped, out)
        vfdm.last_error = out[18:24]
        servo.commit(slot, out[0:6], out[6:12], out[12:18], code)
        return out[24:40].reshape(4, 4), out[40:56].reshape(4, 4), out[56:59], out[59:62]
