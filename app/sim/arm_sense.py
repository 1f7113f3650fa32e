"""One arm's sensor path as one compiled call: the F/T reading and the lab's processing chain.

Per cycle a rig (app/sim/rig.py :meth:`ArmRig.sense`) turns the external wrench on its
mockup into the ODS's input in three stages, each called from Python:

1. the mockup's acceleration over the cycle that just ended, the difference of its
   velocity (NumPy);
2. :meth:`app.sim.ft_sensor.VirtualFTSensor.measure` — load ``m (g − a)``, bias, noise,
   range, delay (:func:`sensor_step`);
3. :meth:`app.sim.ft_sensor.WrenchProcessor.process` — bias and payload compensation,
   low-pass (two filters while the contact gate is open), shift to the COM, deadbands,
   rotation into R and B (:func:`process_cycle`).

:func:`arm_sense` runs the three in one call; :func:`arm_sense_packed`, which the rig
calls, takes the sensor's and the chain's constants as one buffer each
(``VirtualFTSensor.constants``, ``WrenchProcessor.constants``: their attributes are views
of them, so an assignment such as a new calibration is what the next call reads) and the
chain's filter states as one more. What stays in Python is the bookkeeping the
objects do anyway (the noise draws from the sensor's generator, the delay ring's head,
the gate's flags: ``advance`` and ``gate``), so the numbers are those of the stages to
the last bit; the ring of poses that aligns a delayed reading is kept in the call
(:func:`app.sim.ft_sensor.push_pose`, on the chain's buffers). What it saves is the
Python between them and the unpacking of some forty arguments.

Not fused: a sensor slower than the loop (its held readings) and a sensor on the mockup
body (its wrench shifted to the face): their rigs take the stages.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.sim.ft_sensor import ProcessedWrench, process_cycle, push_pose, sensor_step

__all__ = ["OUT_SIZE", "arm_sense", "arm_sense_packed", "arm_sense_rows", "chain_args",
           "sense", "sense_rows", "sensed"]

OUT_SIZE = 24
"""arm_sense's out: the chain's (12,) output (force in R, torque in B, wrench in S), the
raw reading in S (6,), the ODS's part of the processed wrench (force in R, torque in B)."""


@njit(cache=True, fastmath=False)
def arm_sense(wrench_W, T_W_C, T_W_F, v_W, v_W_prev, dt_s, first_cycle, accel,
              normals, s_mass, s_gravity, s_bias, s_noise, s_range, ring, head, fill,
              poses, pose_at, age, R_W_R, p_gravity, payload, inertial,
              p_bias, p_mass, p_com, alpha, contact_alpha, state, contact_state, gate_open,
              reset_slow, db_force, db_torque, soft, scratch, out):
    """One cycle of a rig's sensor path, into out (:data:`OUT_SIZE`).

    accel (3,) := the mockup's acceleration ``(v_W − v_W_prev) / dt_s`` (zeros on the first
    cycle), then v_W_prev := v_W; (T_W_F, T_W_C, accel) kept in the chain's ring of poses
    (:func:`push_pose`: poses, pose_at); the sensor's reading of the wrench on the mockup
    at T_W_C, sensor at T_W_F (:func:`sensor_step`, constants s_*, the delay ring at row
    ``head``) into out[12:18]; the chain on it with the poses and the acceleration of the
    cycle it was taken in, ``age`` cycles ago (:func:`process_cycle`, constants p_*) into
    out[0:12]; out[18:24] := out[0:6].
    """
    for a in range(3):
        accel[a] = 0.0 if first_cycle else (v_W[a] - v_W_prev[a]) / dt_s
        v_W_prev[a] = v_W[a]
    then = poses[push_pose(poses, pose_at, T_W_F, T_W_C, accel, age)]
    T_W_F_then, T_W_C_then = then[0:16].reshape((4, 4)), then[16:32].reshape((4, 4))
    accel_then = then[32:35]
    raw = out[12:18]
    sensor_step(wrench_W, T_W_C, T_W_F, s_mass, s_gravity, accel, normals, s_bias, s_noise,
                s_range, ring, head, fill, raw)
    process_cycle(raw, T_W_F_then, T_W_C_then, R_W_R, p_gravity, payload, accel_then,
                  inertial, p_bias, p_mass, p_com, alpha, contact_alpha, state,
                  contact_state, gate_open, reset_slow, db_force, db_torque, soft, scratch,
                  out[0:12])
    for k in range(6):
        out[18 + k] = out[k]


@njit(cache=True, fastmath=False)
def arm_sense_packed(wrench_W, T_W_C, T_W_F, v_W, v_W_prev, dt_s, first_cycle, normals, sc,
                     ring, head, fill, poses, pose_at, age, R_W_R, pc, px, gate_open,
                     reset_slow, db_force, db_torque, out):
    """:func:`arm_sense` with the sensor's constants in one buffer sc
    (``VirtualFTSensor.constants``), the chain's in pc (``WrenchProcessor.constants``) and
    the chain's filter states and scratch in px (``WrenchProcessor._x``): the same
    kernels on the same numbers, fourteen arguments fewer to unpack per call (the
    acceleration is worked out in a scratch array of its own)."""
    arm_sense(wrench_W, T_W_C, T_W_F, v_W, v_W_prev, dt_s, first_cycle, np.empty(3), normals,
              sc[0], sc[1:4], sc[4:10], sc[10:16], sc[16:22], ring, head, fill,
              poses, pose_at, age, R_W_R, pc[0:3], pc[3] != 0.0,
              pc[4] != 0.0, pc[5:11], pc[11], pc[12:15], pc[15], pc[16], px[0:6],
              px[6:12], gate_open, reset_slow, db_force, db_torque, pc[17] != 0.0,
              px[12:24], out)


@njit(cache=True, fastmath=False)
def arm_sense_rows(s, wrench_W, T_W_C, v_W, T_W_F, v_W_prev, dt_s, first_cycle, R_W_R,
                   gate_open, out, force_R, torque_B, normals, sc, ring, head, fill, poses,
                   pose_at, age, pc, px, reset_slow, db_force, db_torque):
    """:func:`arm_sense_packed` on body s's rows of the cycle's arrays (wrench_W (N, 6),
    T_W_C (N, 4, 4), v_W (N, 3)); then force_R[s], torque_B[s] := the ODS's part of the
    processed wrench (out[0:6]). The arguments from ``normals`` on are
    :func:`chain_args`'. IndexError: s not a row of every one of those arrays."""
    if (s < 0 or s >= wrench_W.shape[0] or s >= T_W_C.shape[0] or s >= v_W.shape[0]
            or s >= force_R.shape[0] or s >= torque_B.shape[0] or wrench_W.shape[1] != 6
            or T_W_C.shape[1] != 4 or T_W_C.shape[2] != 4 or v_W.shape[1] != 3
            or force_R.shape[1] != 3 or torque_B.shape[1] != 3):
        raise IndexError("arm_sense_rows: the satellite is not a row of the cycle's arrays")
    arm_sense_packed(wrench_W[s], T_W_C[s], T_W_F, v_W[s], v_W_prev, dt_s, first_cycle,
                     normals, sc, ring, head, fill, poses, pose_at, age, R_W_R, pc, px,
                     gate_open, reset_slow, db_force, db_torque, out)
    for a in range(3):
        force_R[s, a] = out[a]
        torque_B[s, a] = out[3 + a]


def chain_args(rig, gate_open: bool) -> tuple:
    """The Python side of a cycle of the rig's chain, before its kernel: the sensor's
    bookkeeping (:meth:`~app.sim.ft_sensor.VirtualFTSensor.advance`: the noise draws, the
    delay ring's head) and the gate's (:meth:`~app.sim.ft_sensor.WrenchProcessor.gate`);
    returns the kernels' arguments that follow from them, in :func:`arm_sense_rows`'
    order: (normals, sensor constants, delay ring, head, fill, poses, pose_at, age, chain
    constants, chain state, reset_slow, force deadband, torque deadband)."""
    sensor, proc = rig.sensor, rig.processor
    normals, fill, held = sensor.advance()
    assert held is None  # a sensor that samples every cycle holds nothing
    age = proc.reading_age_cycles = sensor.age_cycles
    db_force, db_torque, reset_slow = proc.gate(gate_open)  # begin's, but for the poses
    return (normals, sensor.constants, sensor._ring, sensor._head, fill, proc._poses,
            proc._pose_at, age, proc.constants, proc._x, reset_slow, db_force, db_torque)


def sensed(rig, out: np.ndarray) -> None:
    """The rig's readings of the cycle from a kernel's out (:data:`OUT_SIZE`)."""
    rig.last_raw_S, rig.last_processed = out[12:18], out[18:24]


def sense(rig, wrench_ext_W: np.ndarray, T_W_C: np.ndarray, v_W: np.ndarray,
          R_W_R: np.ndarray, dt_s: float, first_cycle: bool,
          gate_open: bool) -> ProcessedWrench:
    """:meth:`ArmRig.sense` of a rig whose sensor sits at the flange and samples every
    cycle, in one compiled call; the rig, its sensor and its chain end as after the
    stages (``last_raw_S``, ``last_processed``, ``v_W_prev`` included)."""
    (normals, sc, ring, head, fill, poses, pose_at, age, pc, px, reset_slow, db_force,
     db_torque) = chain_args(rig, gate_open)
    out = np.empty(OUT_SIZE)
    arm_sense_packed(np.asarray(wrench_ext_W, dtype=float), T_W_C, rig.mockup_state_W()[0],
                     v_W, rig.v_W_prev, dt_s, first_cycle, normals, sc, ring, head, fill,
                     poses, pose_at, age, R_W_R, pc, px, gate_open, reset_slow, db_force,
                     db_torque, out)
    sensed(rig, out)
    return ProcessedWrench(out[0:3], out[3:6], out[6:12])


def sense_rows(rig, wrench_W: np.ndarray, T_W_C: np.ndarray, v_W: np.ndarray,
               R_W_R: np.ndarray, dt_s: float, first_cycle: bool, gate_open: bool,
               force_R: np.ndarray, torque_B: np.ndarray) -> None:
    """:func:`sense` on the rig's satellite's rows of the cycle's arrays (wrench_W (N, 6),
    T_W_C (N, 4, 4), v_W (N, 3), all C-ordered), its ODS input written into that row of
    force_R and torque_B (N, 3): one call, no views or wrench object in between."""
    out = np.empty(OUT_SIZE)
    arm_sense_rows(rig.satellite, wrench_W, T_W_C, v_W, rig.mockup_state_W()[0],
                   rig.v_W_prev, dt_s, first_cycle, R_W_R, gate_open, out, force_R,
                   torque_B, *chain_args(rig, gate_open))
    rig.last_raw_S, rig.last_processed = out[12:18], out[18:24]  # (sensed(), inline)
