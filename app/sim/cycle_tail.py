"""The hil cycle's tail as one compiled call: the ODS step, the telemetry row, each arm's
command.

After the ODS input is known, :meth:`app.sim.loop.Emulator.step` (paper Fig. 3) runs
three stages, each its own compiled kernel called from Python:

1. the ODS step and, from its state, each arm's prediction one loop lag ahead
   (:meth:`OrbitalSimulator.advance_and_ahead`, :func:`_rk4_then_leads`);
2. the telemetry row of the cycle's state (:meth:`Recorder.record`,
   :func:`record_row_arm` / :func:`record_row_arms`);
3. each arm's command towards its prediction: TCP target, VFDM, servo, forward
   kinematics (:meth:`ArmRig.command_towards`, :func:`arm_command_towards`).

:func:`tail_one_arm` and :func:`tail_two_arms` call those very kernels in that order on
the same inputs, so the result is the same to the last bit; what they save is the Python
between the stages. The loop takes this path where the tail is those three stages and
nothing else (:meth:`Emulator._fused_tail`: a hil run of one or two fixed arms, no GNC,
no capture, no rail, no servo feedforward, each arm's lead none or among the ODS
step's); ``Emulator.fuse_tail = False`` runs the stages one by one, the oracle the tests
hold this path to (tests/test_cycle_tail.py).
"""

from __future__ import annotations

from numba import njit

from app.sim.arm_command import arm_command_towards
from app.sim.arm_sense import arm_sense_rows
from app.sim.orbital import _rk4_then_leads
from app.sim.telemetry import record_row_arm, record_row_arms

__all__ = ["RANGE_STOP", "sensed_tail_one_arm", "tail_one_arm", "tail_two_arms"]

RANGE_STOP = -2
""":func:`sensed_tail_one_arm`'s row index when the raw force reading is at the sensor's
range: the run stops there, before the ODS step."""


@njit(cache=True, fastmath=False)
def tail_one_arm(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                 ods_out, t_s, orbit_rate, true_force, gnc, rails, n_arms, data, counters,
                 T_R_W, T_W_C, v_W, raw_S, processed, target,
                 T_B_R, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot,
                 sp_prev, q, qd, stopped, out):
    """The tail of a one-arm cycle: ods_out := the ODS step of y and its predictions
    (:func:`_rk4_then_leads`), then the row of the state before it
    (:func:`record_row_arm`, the arm's current T_W_C, v_W, q, raw and processed
    readings), then the arm's command towards ods_out[target]
    (:func:`arm_command_towards`). Returns (the row's index, the VFDM step's scale, the
    servo's stop code); a row index of -1 (a shape that does not fit the row) stops
    before the command, with nothing recorded."""
    _rk4_then_leads(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                    ods_out)
    at = record_row_arm(t_s, y, orbit_rate, force, torque, true_force, gnc, rails, n_arms,
                        data, counters, T_R_W, T_W_C, v_W, q, raw_S, processed)
    if at < 0:
        return at, 1.0, 0
    scale, code = arm_command_towards(T_B_R, ods_out[target], satellite, vfdm_c, vfdm_x,
                                      servo_c, chain_c, ring, slot, sp_prev, q, qd, stopped,
                                      out)
    return at, scale, code


@njit(cache=True, fastmath=False)
def tail_two_arms(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                  ods_out, t_s, orbit_rate, true_force, gnc, rails, n_arms, data, counters,
                  T_R_W, T_W_C, v_W, raw_S, processed, T_W_C2, v_W2, raw_S2, processed2,
                  target, target2,
                  T_B_R, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q,
                  qd, stopped, out,
                  T_B_R2, satellite2, vfdm_c2, vfdm_x2, servo_c2, chain_c2, ring2, slot2,
                  sp_prev2, q2, qd2, stopped2, out2):
    """:func:`tail_one_arm` of a two-arm cycle: the row holds both arms
    (:func:`record_row_arms`), then the first arm's command, then the second's. Returns
    (the row's index, each arm's VFDM scale and stop code)."""
    _rk4_then_leads(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                    ods_out)
    at = record_row_arms(t_s, y, orbit_rate, force, torque, true_force, gnc, rails, n_arms,
                         data, counters, T_R_W, T_W_C, v_W, q, raw_S, processed, T_W_C2,
                         v_W2, q2, raw_S2, processed2)
    if at < 0:
        return at, 1.0, 0, 1.0, 0
    scale, code = arm_command_towards(T_B_R, ods_out[target], satellite, vfdm_c, vfdm_x,
                                      servo_c, chain_c, ring, slot, sp_prev, q, qd, stopped,
                                      out)
    scale2, code2 = arm_command_towards(T_B_R2, ods_out[target2], satellite2, vfdm_c2,
                                        vfdm_x2, servo_c2, chain_c2, ring2, slot2, sp_prev2,
                                        q2, qd2, stopped2, out2)
    return at, scale, code, scale2, code2


@njit(cache=True, fastmath=False)
def sensed_tail_one_arm(s, wrench_W, T_W_C_all, v_W_all, T_W_F, v_W_prev, first_cycle, R_W_R,
                        sensed, range_N,
                        normals, sc, sensor_ring, head, fill, poses, pose_at, age, pc, px,
                        reset_slow, db_force, db_torque,
                        W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                        ods_out, t_s, orbit_rate, true_force, gnc, rails, n_arms, data,
                        counters, T_R_W, T_W_C, v_W, target,
                        T_B_R, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot,
                        sp_prev, q, qd, stopped, out):
    """A one-arm cycle from its F/T chain on, where the chain's output is the ODS input as
    it is (no passivity, no contact gate): the chain of body s with its gate closed
    (:func:`arm_sense_rows`, its readings into ``sensed`` and force[s], torque[s]; the
    arguments from ``normals`` to ``db_torque`` are :func:`arm_sense.chain_args`'); a raw
    force reading at the sensor's range ``range_N`` (> 0: ``[loop] stop_at_sensor_range``)
    ends the call there with :data:`RANGE_STOP`; else :func:`tail_one_arm` on the readings
    just taken. Returns tail_one_arm's (row index, VFDM scale, servo stop code)."""
    arm_sense_rows(s, wrench_W, T_W_C_all, v_W_all, T_W_F, v_W_prev, dt, first_cycle, R_W_R,
                   False, sensed, force, torque, normals, sc, sensor_ring, head, fill, poses,
                   pose_at, age, pc, px, reset_slow, db_force, db_torque)
    if range_N > 0.0:
        for a in range(3):
            if abs(sensed[12 + a]) >= range_N:
                return RANGE_STOP, 1.0, 0
    return tail_one_arm(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt,
                        leads, ods_out, t_s, orbit_rate, true_force, gnc, rails, n_arms, data,
                        counters, T_R_W, T_W_C, v_W, sensed[12:18], sensed[18:24], target,
                        T_B_R, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot,
                        sp_prev, q, qd, stopped, out)
