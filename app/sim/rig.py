"""One arm rig: a UR10e with its servo, its F/T sensor (at the flange, or between the mockup
and its contact face) and processing chain, its VFDM.

Per cycle (paper Fig. 3, one robot's share of it):

* :meth:`ArmRig.mockup_state_W` — servo state → forward kinematics: the actual flange and
  mockup poses and the mockup's twist, in the lab;
* :meth:`ArmRig.sense` — the external wrench on the mockup → virtual F/T reading → the
  lab's processing chain → the wrench the ODS may receive;
* :meth:`ArmRig.command` — the satellite's pose from the ODS, in the base frame → VFDM
  joint set-points → servo step.

And at start-up: find the start posture with the VFDM, make a smooth joint move there,
and calibrate the sensor at rest (as the paper's lab did).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from app.config import EmulatorConfig, RobotConfig
from app.sim import arm_sense
from app.sim.arm_command import OUT_SIZE, ArmCommand, arm_command_towards
from app.sim.feedforward import ServoFeedforward, send, servo_feedforward
from app.sim.frames import satellite_pose
from app.sim.ft_sensor import ProcessedWrench, VirtualFTSensor, WrenchProcessor
from app.sim.rotations import invert_transform
from app.sim.scaling import mockup_mass_kg
from app.sim.sensor_models import sample_every_cycles
from app.sim.servo import UR10eServo, reason_of, safety_box_for_robot
from app.sim.ur10e import (
    T_F_C_from_config,
    T_W_B_from_config,
    TcpChain,
    mockup_state,
    tcp_chain,
)
from app.sim.vfdm import JointLimits, Vfdm

__all__ = ["ArmRig", "build_rig"]


@dataclass
class ArmRig:
    """One UR10e carrying the mockup of satellite ``satellite`` (0-based)."""

    index: int
    satellite: int
    chain: TcpChain
    T_B_R: np.ndarray
    """(4, 4) the CW frame R in the base frame: ``inv(T_W_B) · T_W_R``."""
    vfdm: Vfdm
    servo: UR10eServo
    sensor: VirtualFTSensor
    processor: WrenchProcessor
    mockup_mass_kg: float
    carried_mass_kg: float = 0.0
    """What the F/T sensor carries: the whole mockup at the flange, only the contact face
    with ``[sensor] placement = "mockup"`` (its weight and inertial load are what the chain
    compensates)."""
    T_C_S: np.ndarray | None = None
    """(4, 4) the sensor frame S in the mockup body frame C with ``placement = "mockup"``
    (S at the face's centre of mass, axes the body's); None: S is the flange frame F."""
    lead_s: float = 0.0
    """Lag compensation: the arm is sent where the ODS predicts its satellite this much
    later (app/sim/compensation.py); set at start-up."""
    feedforward: ServoFeedforward | None = None
    """``[compensation] servo_feedforward``: the VFDM's set-points pass the inverse of the
    servo's tracking law (app/sim/feedforward.py) before they are sent."""
    q_start_rad: np.ndarray = field(default_factory=lambda: np.zeros(6))
    v_W_prev: np.ndarray = field(default_factory=lambda: np.zeros(3))
    last_raw_S: np.ndarray = field(default_factory=lambda: np.zeros(6))
    """The raw F/T reading of the last cycle, in S."""
    last_processed: np.ndarray = field(default_factory=lambda: np.zeros(6))
    """The processed wrench of the last cycle: force in R, torque about the COM in B."""
    rest_sd_S: np.ndarray | None = None
    """(6,) the sample standard deviation of each axis of the raw readings at rest, at the
    start-up calibration (the noise the lab measures; None before it)."""
    rest_count: int = 0
    """How many rest readings the calibration averaged."""
    _state_key: tuple | None = field(default=None, repr=False)
    _state: tuple = field(default=(), repr=False)
    _fused: ArmCommand | None = field(default=None, repr=False)

    @property
    def T_W_B(self) -> np.ndarray:
        return self.chain.T_W_B

    @property
    def T_F_C(self) -> np.ndarray:
        return self.chain.T_F_C

    def sensor_pose_W(self, T_W_F: np.ndarray, T_W_C: np.ndarray) -> np.ndarray:
        """T_W_S: the flange pose (placement "flange") or the contact face's in the body
        (placement "mockup": T_W_C · T_C_S)."""
        return T_W_F if self.T_C_S is None else T_W_C @ self.T_C_S

    def _read(self, wrench_ext_W: np.ndarray, T_W_C: np.ndarray, T_W_S: np.ndarray,
              accel_W: np.ndarray | None) -> np.ndarray:
        """The sensor's raw reading. At the flange the whole mockup (its COM at C) hangs on
        it. Between the body and its face only the face does, its mass at the sensor's
        origin: the external wrench (about C) is shifted to S, [F, τ_C + (C − S) × F],
        and the load model's lever arm is then zero (the face's acceleration is taken as
        the COM's: the rotational terms α × r and ω × (ω × r) are left out)."""
        if self.T_C_S is None:
            return self.sensor.measure(wrench_ext_W, T_W_C, T_W_S, accel_W)
        r_SC_W = T_W_C[:3, 3] - T_W_S[:3, 3]
        f = wrench_ext_W[:3]
        at_S = np.concatenate([f, wrench_ext_W[3:] + np.cross(r_SC_W, f)])
        return self.sensor.measure(at_S, T_W_S, T_W_S, accel_W)

    # --- the cycle ----------------------------------------------------------------------

    def mockup_state_W(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T_W_F, T_W_C, v_W, ω_W): actual flange and mockup poses, mockup COM velocity
        and angular velocity, in the lab, from the servo's joint state.

        Kept until that state changes, so the cycle's interaction, its F/T reading and its
        telemetry row share one forward kinematics. The servo hands out new arrays with
        every step or reset (never writing into the old ones), so their identity is the key.
        """
        state = self.servo.state
        key = self._state_key
        if key is None or key[0] is not state.q_rad or key[1] is not state.qd_radps:
            out = (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3))
            mockup_state(state.q_rad, state.qd_radps, *self.chain, *out)
            self._state, self._state_key = out, (state.q_rad, state.qd_radps)
        return self._state

    def sense(self, wrench_ext_W: np.ndarray, T_W_C: np.ndarray, v_W: np.ndarray,
              R_W_R: np.ndarray, dt_s: float, first_cycle: bool,
              gate_open: bool = False) -> ProcessedWrench:
        """The F/T sensor reads the external wrench (W, about the COM) on the mockup at
        T_W_C moving at v_W; the processing chain turns the reading into the ODS's input
        (``gate_open``: a contact is near, the deadbands are lifted).

        The mockup's acceleration, over the cycle that just ended, is the difference of its
        velocity: the mockup's inertial load m·a on the sensor, and the lab's estimate of it
        too (the TCP velocity from the measured joint velocities, differenced; the chain's
        low-pass filters the compensation with the reading), which the chain applies to the
        reading taken at the same instant.

        A sensor at the flange that samples every cycle runs this as one compiled call
        (app/sim/arm_sense.py, the same kernels on the same buffers); :meth:`sense_in_stages`
        is the same cycle stage by stage.
        """
        if self.fused_sense():
            return arm_sense.sense(self, wrench_ext_W, T_W_C, v_W, R_W_R, dt_s, first_cycle,
                                   gate_open)
        return self.sense_in_stages(wrench_ext_W, T_W_C, v_W, R_W_R, dt_s, first_cycle,
                                    gate_open)

    def fused_sense(self) -> bool:
        """Whether :meth:`sense` is one compiled call (app/sim/arm_sense.py): a sensor at
        the flange that samples every cycle (else the stages: a held reading, the wrench
        shifted to the mockup's face)."""
        return self.T_C_S is None and self.sensor.every_cycles == 1.0

    def sense_rows(self, wrench_ext_W: np.ndarray, bodies, R_W_R: np.ndarray, dt_s: float,
                   first_cycle: bool, gate_open: bool, force_R: np.ndarray,
                   torque_B: np.ndarray) -> None:
        """:meth:`sense` of this rig's satellite s on the cycle's arrays (wrench_ext_W
        (N, 6), the :class:`~app.sim.frames.Bodies`): its ODS input (force in R, torque in
        B) into force_R[s] and torque_B[s] (:func:`arm_sense.sense_rows` where
        :meth:`sense` is one call)."""
        s = self.satellite
        if self.fused_sense():
            arm_sense.sense_rows(self, wrench_ext_W, bodies.T_W_C, bodies.v_W, R_W_R, dt_s,
                                 first_cycle, gate_open, force_R, torque_B)
            return
        measured = self.sense_in_stages(wrench_ext_W[s], bodies.T_W_C[s], bodies.v_W[s],
                                        R_W_R, dt_s, first_cycle, gate_open)
        force_R[s], torque_B[s] = measured.force_R_N, measured.torque_B_Nm

    def sense_in_stages(self, wrench_ext_W: np.ndarray, T_W_C: np.ndarray, v_W: np.ndarray,
                        R_W_R: np.ndarray, dt_s: float, first_cycle: bool,
                        gate_open: bool = False) -> ProcessedWrench:
        """:meth:`sense` as its stages: the acceleration, the sensor's reading, the chain."""
        accel_W = (v_W - self.v_W_prev) / dt_s if not first_cycle else np.zeros(3)
        self.v_W_prev = v_W.copy()
        T_W_S = self.sensor_pose_W(self.mockup_state_W()[0], T_W_C)
        raw = self._read(wrench_ext_W, T_W_C, T_W_S, accel_W)
        self.processor.reading_age_cycles = self.sensor.age_cycles
        out = self.processor.process(raw, T_W_S, T_W_C, R_W_R, accel_W, gate_open)
        self.last_raw_S = raw
        self.last_processed = np.concatenate([out.force_R_N, out.torque_B_Nm])
        return out

    def tcp_target_B(self, ods_y: np.ndarray) -> np.ndarray:
        """TCP target ``T_B_C* = T_B_R · T_R_sat`` of the satellite in the ODS state."""
        T = np.empty((4, 4))
        satellite_pose(self.T_B_R, ods_y, self.satellite, T)
        return T

    def command(self, T_B_C_target: np.ndarray) -> None:
        """VFDM set-points towards the target (through the servo feedforward, if on), one
        servo step (which may stop the arm). With ``[vfdm] sync_to_measured`` the virtual
        arm first takes the measured joints.

        Without the feedforward the two run as one compiled call (app/sim/arm_command.py,
        the same kernels on the same buffers), which also leaves the forward kinematics of
        the new joint state in :meth:`mockup_state_W`'s cache; :meth:`command_in_stages` is
        the same cycle stage by stage."""
        fused = self._fused_command()
        if fused is None:
            self.command_in_stages(T_B_C_target)
        else:
            self._keep_state(fused(T_B_C_target))

    def command_towards(self, ods_y: np.ndarray) -> None:
        """:meth:`command` towards :meth:`tcp_target_B` of the ODS state ``ods_y`` (fused:
        the target is worked out in the same compiled call).

        The fused path, the loop's every cycle, calls :func:`arm_command_towards` itself
        (:meth:`fused_command_args`) and does what :meth:`ArmCommand.__call__` and
        :meth:`_keep_state` do after theirs (:meth:`commanded`), for a third of their
        Python."""
        args = self.fused_command_args()
        if args is None:
            self.command(self.tcp_target_B(ods_y))
            return
        T_B_R, satellite, vfdm_c, vfdm_x, servo_c, chain_c, ring, slot, sp_prev, q, qd, \
            stopped, out = args
        scale, code = arm_command_towards(T_B_R, ods_y, satellite, vfdm_c, vfdm_x, servo_c,
                                          chain_c, ring, slot, sp_prev, q, qd, stopped, out)
        self.commanded(scale, code, slot, out)

    def fused_command_args(self) -> tuple | None:
        """:func:`arm_command_towards`'s arguments but the ODS state, in its order, with a
        new ``out`` (None where the command takes the stages: the servo feedforward)."""
        fused = self._fused
        if (fused is None or self.feedforward is not None or fused.vfdm is not self.vfdm
                or fused.servo is not self.servo or fused.chain is not self.chain):
            fused = self._fused_command()
            if fused is None:
                return None
        vfdm, servo = self.vfdm, self.servo
        st, ring = servo.state, servo._ring
        return (self.T_B_R, self.satellite, vfdm.constants, vfdm._x, fused.servo_constants,
                fused.chain_constants, ring, servo._slot if len(ring) else -1,  # delay_slot
                servo._sp_prev, st.q_rad, st.qd_radps, st.stopped, np.empty(OUT_SIZE))

    def commanded(self, scale: float, code: int, slot: int, out: np.ndarray) -> None:
        """After :func:`arm_command_towards` on :meth:`fused_command_args` (``slot``,
        ``out``): the VFDM's ``last_scale`` and ``last_error``, the servo's ring slot, new
        state arrays and stop (:meth:`UR10eServo.commit`), the forward kinematics cache,
        all as the stages leave them."""
        vfdm, servo = self.vfdm, self.servo
        st = servo.state
        vfdm.last_scale = scale
        vfdm.last_error = out[18:24]
        if slot >= 0:
            servo._slot = (slot + 1) % len(servo._ring)
        q, qd = st.q_rad, st.qd_radps = out[0:6], out[6:12]
        st.qdd_radps2 = out[12:18]
        if code:
            st.stopped, st.reason = True, reason_of(code)
        self._state = (out[24:40].reshape(4, 4), out[40:56].reshape(4, 4), out[56:59],
                       out[59:62])
        self._state_key = (q, qd)

    def _fused_command(self) -> ArmCommand | None:
        """The fused command path of this VFDM, servo and chain (None: the stages, with
        the servo feedforward)."""
        if self.feedforward is not None:
            return None
        fused = self._fused
        if (fused is None or fused.vfdm is not self.vfdm or fused.servo is not self.servo
                or fused.chain is not self.chain):
            fused = self._fused = ArmCommand(self.vfdm, self.servo, self.chain)
        return fused

    def _keep_state(self, fk: tuple) -> None:
        """Keep the forward kinematics the fused call made of the new joint state as
        :meth:`mockup_state_W`'s."""
        st = self.servo.state
        self._state, self._state_key = fk, (st.q_rad, st.qd_radps)

    def command_in_stages(self, T_B_C_target: np.ndarray) -> None:
        """:meth:`command` as its stages: the VFDM's solve, then the feedforward (if on)
        and the servo's step."""
        if self.vfdm.cfg.sync_to_measured:
            self.vfdm.q_rad[:] = self.servo.state.q_rad
        q_d = self.vfdm.solve(T_B_C_target)
        send(self.servo, self.feedforward, q_d)

    # --- start-up -------------------------------------------------------------------------

    def solve_start_posture(self, T_B_C_target: np.ndarray, max_steps: int,
                            tick=None) -> tuple[np.ndarray | None, float]:
        """(q, position error m): joint positions that put the TCP at the target, found by
        the VFDM run on its virtual model only until converged (q None if it does not).
        ``tick``: called every 500 steps (a supervisor's heartbeat)."""
        vfdm = Vfdm(self.vfdm.cfg, self.T_F_C, self.vfdm.q_rad, limits=None)
        for k in range(max_steps):
            if tick is not None and k % 500 == 0:
                tick()
            q = vfdm.solve(T_B_C_target)
            err = vfdm.last_error
            if np.linalg.norm(err[:3]) < 1e-5 and np.linalg.norm(err[3:]) < 1e-4:
                return q, float(np.linalg.norm(err[:3]))
        # the error the VFDM sees is clamped: report the true distance left
        return None, float(np.linalg.norm(T_B_C_target[:3, 3] - vfdm.tcp_pose()[:3, 3]))

    def move_to(self, q_goal_rad: np.ndarray, dt_s: float) -> None:
        """Cosine-profiled joint move, peak speed at most half of each joint's limit, then
        0.2 s at rest."""
        q0 = self.servo.state.q_rad.copy()
        dq = q_goal_rad - q0
        limits = self.servo.speed_limits_radps * 0.5
        duration = max(0.5, float(np.max(np.abs(dq) * (np.pi / 2) / limits)))
        n = int(np.ceil(duration / dt_s))
        for k in range(1, n + 1):
            s = 0.5 * (1.0 - np.cos(np.pi * k / n))
            self.servo.step(q0 + s * dq)
        for _ in range(int(0.2 / dt_s)):
            self.servo.step(q_goal_rad)

    def rest_reading(self) -> np.ndarray:
        """One servo step at the start posture and a raw F/T reading with nothing touching."""
        self.servo.step(self.q_start_rad)
        T_W_F, T_W_C, _, _ = self.mockup_state_W()
        return self._read(np.zeros(6), T_W_C, self.sensor_pose_W(T_W_F, T_W_C), None)

    def calibrate(self, readings_S: np.ndarray) -> None:
        """Payload calibration at rest with the known mass and COM of what the sensor
        carries (the mockup at the flange, the face on the body), and the noise the
        readings show (``rest_sd_S``); the VFDM starts from where the arm is."""
        T_W_F, T_W_C, _, _ = self.mockup_state_W()
        if len(readings_S) > 1:
            self.rest_sd_S = np.std(readings_S, axis=0, ddof=1)
        self.rest_count = len(readings_S)
        com_S = self.T_F_C[:3, 3] if self.T_C_S is None else np.zeros(3)
        self.processor.calibrate(readings_S, self.sensor_pose_W(T_W_F, T_W_C)[:3, :3],
                                 mass_kg=self.carried_mass_kg, com_F_m=com_S)
        self.processor.reset()
        self.vfdm.reset(self.servo.state.q_rad)
        if self.feedforward is not None:
            self.feedforward.reset(self.servo.state.q_rad)


def build_rig(index: int, robot: RobotConfig, config: EmulatorConfig, T_W_R: np.ndarray,
              rng: np.random.Generator) -> ArmRig:
    """The rig of ``robot`` (config.robots[index]) at its home posture, its base fixed
    (a robot on a rail: app/sim/rail_rig.py build_cell)."""
    dt_s = 1.0 / config.loop.rate_hz
    gravity_W = np.array(config.lab.gravity_mps2)
    sat = config.satellite_index(robot.satellite)
    T_W_B, T_F_C = T_W_B_from_config(robot), T_F_C_from_config(robot)
    q_home = np.array(robot.q_home_rad)
    mass = mockup_mass_kg(config.satellites[sat], config)
    on_body = config.sensor.placement == "mockup"
    carried = config.sensor.face_mass_kg if on_body else mass  # what the sensor carries
    T_C_S = None
    if on_body:
        T_C_S = np.eye(4)
        T_C_S[:3, 3] = config.sensor.face_position_m
    rig = ArmRig(
        index=index,
        satellite=sat,
        chain=tcp_chain(T_W_B, T_F_C),
        T_B_R=invert_transform(T_W_B) @ T_W_R,
        vfdm=Vfdm(config.vfdm, T_F_C, q_home, JointLimits.of_servo(config.servo, dt_s)),
        servo=UR10eServo(config.servo, dt_s, q_home, safety_box_for_robot(robot)),
        sensor=VirtualFTSensor(config.sensor, carried, gravity_W, rng, config.loop.rate_hz),
        processor=WrenchProcessor(
            config.wrench, config.loop.rate_hz, gravity_W, config.sensor.delay_cycles,
            config.sensor.delay_cycles + math.ceil(
                sample_every_cycles(config.sensor.sample_rate_hz, config.loop.rate_hz)) - 1),
        mockup_mass_kg=mass,
        carried_mass_kg=carried,
        T_C_S=T_C_S,
        feedforward=servo_feedforward(config, q_home),
    )
    return rig
