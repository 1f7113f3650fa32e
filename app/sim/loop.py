"""The emulation loop (DESIGN.md "The loop"; paper Fig. 3), one control cycle per `step`.

HIL mode, per cycle and per arm/satellite pair::

    joint state q ─► FK: actual mockup pose ─► physical interaction on the ACTUAL mockups
    (contact between mockups, operator's hand) ─► virtual F/T sensor ─► wrench processing
    ─► ODS step (all satellites) ─► TCP target in the base frame ─► VFDM ─► servo

Ideal mode has no arms: contact is computed directly between the ODS poses, with no
sensor, no delay and no servo. It is the reference the HIL run is measured against.

The loop is single-threaded and owns all its state. Anything from outside (a REST push,
a gizmo drag) arrives as a command through :meth:`Emulator.post` and is consumed at the
start of the next cycle.

Speed: every stage has a compiled (numba) path next to its Python reference path, on by
default and switched by a ``use_kernel`` attribute (the loop's own bookkeeping: satellite
poses, TCP targets, the idle hand and the telemetry row, see :mod:`app.sim.loop_kernel`);
:meth:`Emulator.set_compiled` flips all of them at once. Both paths give the same results
up to rounding.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from app.config import EmulatorConfig
from app.propagate import pulse_wrenches
from app.sim.contact import BoxContactModel
from app.sim.ft_sensor import VirtualFTSensor, WrenchProcessor
from app.sim.loop_kernel import ods_states_W, record_arm, record_satellites, satellite_pose
from app.sim.orbital import OrbitalSimulator
from app.sim.passivity import PassivityController, is_zero
from app.sim.rotations import invert_transform, make_transform, matrix_to_quat, quat_to_matrix
from app.sim.servo import UR10eServo, safety_box_for_robot
from app.sim.telemetry import TelemetryBuffer, robot_columns, satellite_columns
from app.sim.ur10e import T_F_C_from_config, T_W_B_from_config, UR10e
from app.sim.ur10e_kernel import TcpChain, mockup_state, tcp_chain
from app.sim.vfdm import Vfdm, vfdm_kernel_available

# --- commands -------------------------------------------------------------------------


@dataclass(frozen=True)
class Push:
    """A hand pushing satellite `satellite` (0-based) with force_R_N (in R) for duration_s."""

    satellite: int
    force_R_N: tuple[float, float, float]
    duration_s: float


@dataclass(frozen=True)
class HandAnchor:
    """The operator's hand (gizmo) at anchor_W_m, spring-coupled to the mockup; None lets go."""

    satellite: int
    anchor_W_m: tuple[float, float, float] | None


Command = Push | HandAnchor


# --- one arm ----------------------------------------------------------------------------


@dataclass
class Arm:
    """One UR10e with its mockup, servo, F/T sensor and processing chain."""

    index: int
    satellite: int
    kin: UR10e
    T_W_B: np.ndarray
    T_F_C: np.ndarray
    vfdm: Vfdm
    servo: UR10eServo
    sensor: VirtualFTSensor
    processor: WrenchProcessor
    passivity: tuple[PassivityController, PassivityController] | None = None
    q_start_rad: np.ndarray = field(default_factory=lambda: np.zeros(6))
    v_W_prev: np.ndarray = field(default_factory=lambda: np.zeros(3))
    last_raw_S: np.ndarray = field(default_factory=lambda: np.zeros(6))
    last_processed: np.ndarray = field(default_factory=lambda: np.zeros(6))
    use_kernel: bool = True
    """Mockup pose and twist through app.sim.ur10e_kernel (same results as pinocchio)."""
    _state_key: tuple | None = field(default=None, repr=False)
    _state: tuple = field(default=(), repr=False)
    _chain: TcpChain | None = field(default=None, repr=False)

    def mockup_state_W(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Actual flange pose, mockup pose, and mockup COM velocity / angular velocity in W.

        Computed from the servo's joint state; kept until that state changes, so the
        cycle's interaction and its telemetry row share one forward kinematics.
        """
        state = self.servo.state
        key = (id(state), state.q_rad.tobytes(), state.qd_radps.tobytes())
        if self._state_key != key:
            if self.use_kernel:
                self._state = self._mockup_state_compiled(state.q_rad, state.qd_radps)
            else:
                self._state = self._mockup_state_reference(state.q_rad, state.qd_radps)
            self._state_key = key
        return self._state

    def _mockup_state_reference(self, q: np.ndarray, qd: np.ndarray) -> tuple:
        """Pinocchio FK and TCP Jacobian (the reference path)."""
        T_W_F = self.T_W_B @ self.kin.fk(q)
        T_W_C = T_W_F @ self.T_F_C
        twist_B = self.kin.tcp_jacobian(q, self.T_F_C) @ qd
        R_W_B = self.T_W_B[:3, :3]
        return T_W_F, T_W_C, R_W_B @ twist_B[:3], R_W_B @ twist_B[3:]

    def _mockup_state_compiled(self, q: np.ndarray, qd: np.ndarray) -> tuple:
        """The same through one call of ur10e_kernel.mockup_state."""
        if self._chain is None:
            self._chain = tcp_chain(self.kin.model, self.kin.flange_id, self.T_W_B, self.T_F_C)
        out = (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3))
        mockup_state(q, qd, *self._chain, *out)
        return out


# --- the emulator -----------------------------------------------------------------------

STATUSES = ("idle", "running", "finished", "safety_stop", "stopped")


class Emulator:
    """Dual-arm (any number of arms) on-orbit emulation loop."""

    def __init__(self, config: EmulatorConfig, mode: str | None = None) -> None:
        self.config = config
        self.mode = mode or config.loop.mode
        if self.mode not in ("hil", "ideal"):
            raise ValueError(f"mode must be 'hil' or 'ideal', got {self.mode!r}")
        if self.mode == "hil" and not config.robots:
            raise ValueError("hil mode needs at least one [[robots]] entry")
        self.dt_s = 1.0 / config.loop.rate_hz
        self.T_W_R = make_transform(
            quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m
        )
        self.T_R_W = invert_transform(self.T_W_R)
        self.R_W_R = self.T_W_R[:3, :3]
        self.gravity_W = np.array(config.lab.gravity_mps2)
        self.ods = OrbitalSimulator.from_config(config)
        self.n_sat = len(config.satellites)
        self.contact = BoxContactModel.from_satellites(config.satellites, config.materials)
        self.arms: list[Arm] = []
        if self.mode == "hil":
            seeds = np.random.SeedSequence(config.loop.seed).spawn(len(config.robots))
            for i, robot in enumerate(config.robots):
                self.arms.append(self._build_arm(i, robot, np.random.default_rng(seeds[i])))
        self.columns = self._columns()
        self.telemetry = TelemetryBuffer(self.columns, config.loop.telemetry_capacity)
        self.status = "idle"
        self.safety_stop: dict | None = None
        self.cycles = 0
        self.cycle_time_ns: list[int] = []
        self._commands: list[Command] = []
        self._pushes: list[tuple[int, np.ndarray, float]] = []  # (sat, force_R, until_s)
        self._anchors: dict[int, np.ndarray] = {}
        self.applied_force_R = np.zeros((self.n_sat, 3))
        self.applied_torque_B = np.zeros((self.n_sat, 3))
        self.true_force_R = np.zeros((self.n_sat, 3))
        self.contact_active = False
        # constants of the compiled bookkeeping: each arm's T_B_R, the scripted pulse windows
        self._T_B_R = [invert_transform(arm.T_W_B) @ self.T_W_R for arm in self.arms]
        self._pulse_windows = [(p.start_s, p.end_s) for p in config.pulses]
        self._uncarried = sorted(set(range(self.n_sat)) - {arm.satellite for arm in self.arms})
        self.use_kernel = True
        """Poses, TCP targets, the idle hand and the telemetry row through loop_kernel."""
        self._load_kernels()

    def set_compiled(self, on: bool) -> None:
        """Switch every stage's compiled path on (default) or back to the Python reference."""
        self.use_kernel = self.ods.use_kernel = on
        for arm in self.arms:
            arm.use_kernel = arm.servo.use_kernel = on
            arm.sensor.use_kernel = arm.processor.use_kernel = on
            arm.vfdm.use_kernel = on and vfdm_kernel_available()

    # --- construction ---------------------------------------------------------------------

    def _build_arm(self, index: int, robot, rng: np.random.Generator) -> Arm:
        cfg = self.config
        sat = cfg.satellite_index(robot.satellite)
        kin = UR10e()
        T_F_C = T_F_C_from_config(robot)
        q_home = np.array(robot.q_home_rad)
        mass = cfg.satellites[sat].mass_kg
        return Arm(
            index=index,
            satellite=sat,
            kin=kin,
            T_W_B=T_W_B_from_config(robot),
            T_F_C=T_F_C,
            vfdm=Vfdm(cfg.vfdm, T_F_C, q_home),
            servo=UR10eServo(cfg.servo, self.dt_s, q_home, safety_box_for_robot(robot, kin)),
            sensor=VirtualFTSensor(cfg.sensor, mass, self.gravity_W, rng),
            processor=WrenchProcessor(cfg.wrench, cfg.loop.rate_hz, self.gravity_W),
            passivity=self._build_passivity(),
        )

    def _build_passivity(self) -> tuple[PassivityController, PassivityController] | None:
        pc = self.config.passivity
        if not pc.enabled:
            return None
        return (
            PassivityController(self.dt_s, pc.idle_reset_s),
            PassivityController(self.dt_s, pc.idle_reset_s),
        )

    def _columns(self) -> list[str]:
        cols = ["t_s", *satellite_columns(self.n_sat), *robot_columns(len(self.arms))]
        cols += [f"sat{i + 1}_true_f{a}_N" for i in range(self.n_sat) for a in "xyz"]
        return cols

    def _load_kernels(self) -> None:
        """Run each compiled path once on scratch objects, so that numba loads the kernels
        from its cache now rather than in the first timed cycles; the simulation's state is
        not touched."""
        cfg, dt = self.config, self.dt_s
        force, torque = np.zeros((self.n_sat, 3)), np.zeros((self.n_sat, 3))
        ods = OrbitalSimulator(self.ods.params, self.ods.y.copy())
        ods.step(force, torque, dt)
        _ = ods.omega_rel_radps  # loads its kernel
        row = np.empty(len(self.columns))
        k = record_satellites(0.0, self.ods.y, self.ods.params.orbit_rate_radps, force, torque,
                              row)
        self._ods_states_W()
        if not self.arms:
            return
        arm = self.arms[0]
        T_W_F, T_W_C, v_W, _ = arm.mockup_state_W()
        q = arm.servo.state.q_rad
        record_arm(self.T_R_W, T_W_C, v_W, q, arm.last_raw_S, row, k)
        Vfdm(cfg.vfdm, arm.T_F_C, q).solve(self.tcp_target_B(arm))
        UR10eServo(cfg.servo, dt, q, arm.servo.safety).step(q)
        rng = np.random.default_rng(0)
        raw = VirtualFTSensor(cfg.sensor, 1.0, self.gravity_W, rng).measure(
            np.zeros(6), T_W_C, T_W_F, np.zeros(3)
        )
        WrenchProcessor(cfg.wrench, cfg.loop.rate_hz, self.gravity_W).process(
            raw, T_W_F, T_W_C, self.R_W_R, np.zeros(3)
        )

    # --- poses --------------------------------------------------------------------------

    def satellite_pose_W(self, i: int) -> np.ndarray:
        """ODS pose of satellite i in the lab: T_W_R · T_R_sat."""
        if self.use_kernel:
            T = np.empty((4, 4))
            satellite_pose(self.T_W_R, self.ods.y, i, T)
            return T
        T_R_S = make_transform(quat_to_matrix(self.ods.attitude_wxyz[i]), self.ods.position_m[i])
        return self.T_W_R @ T_R_S

    def tcp_target_B(self, arm: Arm) -> np.ndarray:
        """TCP target of an arm: T_B_C* = inv(T_W_B) · T_W_R · T_R_sat."""
        if self.use_kernel:
            T = np.empty((4, 4))
            satellite_pose(self._T_B_R[arm.index], self.ods.y, arm.satellite, T)
            return T
        return invert_transform(arm.T_W_B) @ self.satellite_pose_W(arm.satellite)

    # --- start-up -------------------------------------------------------------------------

    def prepare(self, settle_s: float = 0.5) -> None:
        """Move every arm to its start pose, calibrate its F/T sensor, start the clock.

        The start posture is found by the VFDM itself (run on its virtual model only until
        converged); the arm then makes a smooth joint move there within half its speed
        limits, rests for `settle_s` while the sensor readings are averaged for the payload
        calibration (bias with the known mockup mass and COM, as the paper's lab did).
        """
        for arm in self.arms:
            arm.q_start_rad = self._solve_start_posture(arm)
            self._joint_move(arm, arm.q_start_rad)
        rest = {arm.index: [] for arm in self.arms}
        for _ in range(int(round(settle_s / self.dt_s))):
            for arm in self.arms:
                arm.servo.step(arm.q_start_rad)
                T_W_F, T_W_C, _, _ = arm.mockup_state_W()
                rest[arm.index].append(arm.sensor.measure(np.zeros(6), T_W_C, T_W_F))
        for arm in self.arms:
            if arm.servo.stopped:
                self._safety_stop(arm, arm.servo.reason)
                return
            T_W_F, _, _, _ = arm.mockup_state_W()
            sat = self.config.satellites[arm.satellite]
            arm.processor.calibrate(
                np.array(rest[arm.index]), T_W_F[:3, :3], mass_kg=sat.mass_kg,
                com_F_m=arm.T_F_C[:3, 3],
            )
            arm.processor.reset()
            arm.vfdm.reset(arm.servo.state.q_rad)
        self.status = "running"

    def _solve_start_posture(self, arm: Arm) -> np.ndarray:
        target = self.tcp_target_B(arm)
        vfdm = Vfdm(self.config.vfdm, arm.T_F_C, arm.vfdm.q_rad)
        steps = int(self.config.loop.approach_timeout_s * self.config.loop.rate_hz)
        for _ in range(steps):
            q = vfdm.solve(target)
            err = vfdm.last_error
            if np.linalg.norm(err[:3]) < 1e-5 and np.linalg.norm(err[3:]) < 1e-4:
                return q
        raise RuntimeError(
            f"robot {arm.index + 1}: start pose of satellite "
            f"{self.config.satellites[arm.satellite].name!r} not reached "
            f"(error {np.linalg.norm(err[:3]):.4f} m): is it within reach?"
        )

    def _joint_move(self, arm: Arm, q_goal: np.ndarray) -> None:
        """Cosine-profiled joint move, peak speed at most half of each joint's limit."""
        q0 = arm.servo.state.q_rad.copy()
        dq = q_goal - q0
        limits = arm.servo.speed_limits_radps * 0.5
        duration = max(0.5, float(np.max(np.abs(dq) * (np.pi / 2) / limits)))
        n = int(np.ceil(duration / self.dt_s))
        for k in range(1, n + 1):
            s = 0.5 * (1.0 - np.cos(np.pi * k / n))
            arm.servo.step(q0 + s * dq)
        for _ in range(int(0.2 / self.dt_s)):
            arm.servo.step(q_goal)

    # --- commands -------------------------------------------------------------------------

    def post(self, command: Command) -> None:
        """Queue a command; it takes effect at the start of the next cycle."""
        if not 0 <= command.satellite < self.n_sat:
            raise ValueError(
                f"satellite must be between 1 and {self.n_sat}, got {command.satellite + 1}"
            )
        self._commands.append(command)

    def _consume_commands(self) -> None:
        for cmd in self._commands:
            if isinstance(cmd, Push):
                until = self.ods.t_s + cmd.duration_s
                self._pushes.append((cmd.satellite, np.array(cmd.force_R_N), until))
            elif cmd.anchor_W_m is None:
                self._anchors.pop(cmd.satellite, None)
            else:
                self._anchors[cmd.satellite] = np.array(cmd.anchor_W_m)
        self._commands.clear()
        t = self.ods.t_s
        self._pushes = [p for p in self._pushes if t < p[2] - 1e-12]

    # --- the cycle ------------------------------------------------------------------------

    def hand_wrenches_W(self, p_W_C: np.ndarray, R_W_C: np.ndarray) -> np.ndarray:
        """The operator's hand on each mockup: scripted pulses, REST pushes and the gizmo.

        Pulses and pushes act through the COM with the force they specify (a hand that
        keeps its push steady); the gizmo's hand is a spring from its anchor to the COM,
        saturated at the hand's maximum force. Returns (N, 6) wrenches in W about each COM.
        """
        if self.use_kernel and self._hand_idle():
            return np.zeros((self.n_sat, 6))
        wrench = np.zeros((self.n_sat, 6))
        force_R, torque_B = pulse_wrenches(self.config, self.ods.t_s)
        for sat, f_R, _ in self._pushes:
            force_R[sat] += f_R
        wrench[:, :3] = force_R @ self.R_W_R.T
        for i in range(self.n_sat):
            wrench[i, 3:] = R_W_C[i] @ torque_B[i]
        hand = self.config.hand
        for sat, anchor in self._anchors.items():
            f = hand.stiffness_Npm * (anchor - p_W_C[sat])
            norm = float(np.linalg.norm(f))
            if norm > hand.max_force_N:
                f *= hand.max_force_N / norm
            wrench[sat, :3] += f
        return wrench

    def _hand_idle(self) -> bool:
        """No pulse, push or gizmo acts now (the hand's wrenches are all zero)."""
        t = self.ods.t_s
        return not (self._pushes or self._anchors
                    or any(start <= t < end for start, end in self._pulse_windows))

    def step(self) -> None:
        """One control cycle."""
        if self.status == "idle":
            self.prepare()
        if self.status != "running":
            return
        t0 = time.perf_counter_ns()
        self._consume_commands()
        if self.mode == "hil":
            force_R, torque_B = self._interact_hil()
        else:
            force_R, torque_B = self._interact_ideal()
        self.applied_force_R, self.applied_torque_B = force_R, torque_B
        self._record()
        self.ods.step(force_R, torque_B, self.dt_s)
        if self.mode == "hil":
            for arm in self.arms:
                q_sp = arm.vfdm.solve(self.tcp_target_B(arm))
                arm.servo.step(q_sp)
                if arm.servo.stopped:
                    self._safety_stop(arm, arm.servo.reason)
        self.cycles += 1
        self.cycle_time_ns.append(time.perf_counter_ns() - t0)

    def _ods_states_W(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every satellite's ODS pose (N, 4, 4) and COM velocity (N, 3) in W, and zero
        angular velocities (N, 3): the HIL interaction's view of satellites without an arm."""
        n = self.n_sat
        w_W = np.zeros((n, 3))
        if self.use_kernel:
            T_W_C, v_W = np.empty((n, 4, 4)), np.empty((n, 3))
            ods_states_W(self.T_W_R, self.ods.y, T_W_C, v_W)
            return T_W_C, v_W, w_W
        T_W_C = np.array([self.satellite_pose_W(i) for i in range(n)])
        v_W = np.zeros((n, 3))
        for i in range(n):
            v_W[i] = self.R_W_R @ self.ods.velocity_mps[i]
        return T_W_C, v_W, w_W

    def _interact_hil(self) -> tuple[np.ndarray, np.ndarray]:
        """Contact and hand on the actual mockups, measured by each arm's F/T sensor."""
        n = self.n_sat
        T_W_C, v_W, w_W = self._ods_states_W()  # satellites without an arm: ODS pose
        T_W_F = {}
        for arm in self.arms:
            T_W_F[arm.index], T_W_C[arm.satellite], v_W[arm.satellite], w_W[arm.satellite] = (
                arm.mockup_state_W()
            )
        contact = self.contact.compute(T_W_C, v_W, w_W)
        self.contact_active = any(c.normal_force_N > 0 for c in contact.contacts)
        p_W, R_W_C = T_W_C[:, :3, 3], T_W_C[:, :3, :3]
        external_W = contact.wrench_W + self.hand_wrenches_W(p_W, R_W_C)
        self.true_force_R = external_W[:, :3] @ self.R_W_R
        force_R = np.zeros((n, 3))
        torque_B = np.zeros((n, 3))
        for i in self._uncarried:  # no sensor on a satellite without an arm: the wrench as is
            force_R[i] = self.true_force_R[i]
            torque_B[i] = R_W_C[i].T @ external_W[i, 3:]
        for arm in self.arms:
            s = arm.satellite
            accel_W = (v_W[s] - arm.v_W_prev) / self.dt_s if self.cycles else np.zeros(3)
            arm.v_W_prev = v_W[s].copy()
            raw = arm.sensor.measure(external_W[s], T_W_C[s], T_W_F[arm.index], accel_W)
            out = arm.processor.process(raw, T_W_F[arm.index], T_W_C[s], self.R_W_R, accel_W)
            arm.last_raw_S = raw
            arm.last_processed = np.concatenate([out.force_R_N, out.torque_B_Nm])
            force_R[s], torque_B[s] = out.force_R_N, out.torque_B_Nm
            if arm.passivity is not None:
                force_R[s], torque_B[s] = self._passivate(arm, out, v_W[s], w_W[s], R_W_C[s])
        return force_R, torque_B

    def _passivate(self, arm: Arm, out, v_W, w_W, R_W_C) -> tuple[np.ndarray, np.ndarray]:
        """The ODS input of an arm's satellite through its passivity controllers."""
        s = arm.satellite
        pc_f, pc_t = arm.passivity
        force, torque = out.force_R_N, out.torque_B_Nm
        if is_zero(force):  # the velocities are only needed while something acts
            pc_f.idle()
        else:
            force = pc_f.step(force, self.ods.velocity_mps[s], self.R_W_R.T @ v_W)
        if is_zero(torque):
            pc_t.idle()
        else:
            torque = pc_t.step(torque, self.ods.omega_rel_radps[s], R_W_C.T @ w_W)
        return force, torque

    def _interact_ideal(self) -> tuple[np.ndarray, np.ndarray]:
        """Contact between the ODS poses and the hand, applied exactly (no sensor)."""
        n = self.n_sat
        T_W_C = [self.satellite_pose_W(i) for i in range(n)]
        R_W_C = [T[:3, :3] for T in T_W_C]
        v_W = self.ods.velocity_mps @ self.R_W_R.T
        w_W = np.array([R_W_C[i] @ self.ods.omega_rel_radps[i] for i in range(n)])
        contact = self.contact.compute(T_W_C, v_W, w_W)
        self.contact_active = any(c.normal_force_N > 0 for c in contact.contacts)
        p_W = np.array([T[:3, 3] for T in T_W_C])
        external_W = contact.wrench_W + self.hand_wrenches_W(p_W, R_W_C)
        force_R = external_W[:, :3] @ self.R_W_R
        torque_B = np.array([R_W_C[i].T @ external_W[i, 3:] for i in range(n)])
        self.true_force_R = force_R
        return force_R, torque_B

    def _safety_stop(self, arm: Arm, reason: str) -> None:
        self.status = "safety_stop"
        self.safety_stop = {"robot": arm.index + 1, "t_s": self.ods.t_s, "reason": reason}

    # --- telemetry --------------------------------------------------------------------------

    def mockup_pose_R(self, arm: Arm) -> tuple[np.ndarray, np.ndarray]:
        """Actual mockup COM position and attitude (wxyz) in R, from the robot's FK."""
        T_R_C = self.T_R_W @ arm.mockup_state_W()[1]
        return T_R_C[:3, 3], matrix_to_quat(T_R_C[:3, :3])

    def mockup_velocity_R(self, arm: Arm) -> np.ndarray:
        """Actual mockup COM velocity in R (from the joint velocities)."""
        return self.T_R_W[:3, :3] @ arm.mockup_state_W()[2]

    def _record(self) -> None:
        """Append the telemetry row of the current state (columns: :meth:`_columns`)."""
        if self.use_kernel:
            self._record_compiled()
            return
        ods = self.ods
        parts = [
            [ods.t_s],
            np.hstack(
                [ods.position_m, ods.velocity_mps, ods.attitude_wxyz, ods.omega_rel_radps,
                 self.applied_force_R, self.applied_torque_B]
            ).ravel(),
        ]
        for arm in self.arms:
            p_R, q_R = self.mockup_pose_R(arm)
            parts += [p_R, q_R, self.mockup_velocity_R(arm), arm.servo.state.q_rad, arm.last_raw_S]
        parts.append(self.true_force_R.ravel())
        self.telemetry.append(np.concatenate(parts))

    def _record_compiled(self) -> None:
        """:meth:`_record` written in place into the telemetry buffer's next row."""
        ods = self.ods
        row = self.telemetry.next_row()
        k = record_satellites(ods.t_s, ods.y, ods.params.orbit_rate_radps,
                              self.applied_force_R, self.applied_torque_B, row)
        for arm in self.arms:
            _, T_W_C, v_W, _ = arm.mockup_state_W()
            k = record_arm(self.T_R_W, T_W_C, v_W, arm.servo.state.q_rad, arm.last_raw_S,
                           row, k)
        row[k:] = self.true_force_R.ravel()

    # --- running -----------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        return self.ods.t_s

    def run(self, duration_s: float, progress=None) -> None:
        """Run until duration_s of scenario time, a safety stop, or stop()."""
        if self.status == "idle":
            self.prepare()
        n = int(round(duration_s / self.dt_s))
        for k in range(n):
            if self.status != "running":
                break
            self.step()
            if progress is not None and k % 500 == 0:
                progress(k, n)
        if self.status == "running":
            self.status = "finished"
        if self.cycles:
            self._record()  # the final state, whatever ended the run
