"""Reference implementations (oracles) of the numeric core, for the tests only.

app/sim/ has one compiled (numba) implementation per stage. The maths they replace lives on
here, written for readability rather than speed, with Pinocchio doing the rigid-body work:

* :func:`build_model` — the UR10e as a Pinocchio model built from the DH table below
  (typed in independently of :mod:`app.sim.ur10e`), frames ``"flange"`` and ``"tcp"``;
  :func:`virtual_model` — the VFDM's conditioned-inertia copy of it (paper Table 1);
* :class:`PinArm` — forward kinematics, the TCP Jacobian (LOCAL_WORLD_ALIGNED, shifted from
  the flange to the TCP) and ``H⁻¹ τ`` by ABA at zero velocity;
* :class:`RefVfdm` — one VFDM internal step with Pinocchio (paper Eqs. 9-13);
  :class:`RefRailVfdm` — the same on the 7-joint rail chain (:func:`build_rail_model`),
  with the null-space posture term by the dynamically consistent projector;
* :class:`RefServo` — the simulated UR10e servo: delay ring, protective-stop checks,
  second-order tracking, braking, saturation;
* :func:`sensor_load_S`, :class:`RefSensor`, :class:`RefProcessor`, :func:`deadband` — the
  F/T sensor's load, reading and delay ring, and the lab's processing chain, in NumPy;
* :func:`omega_relative` — the body's angular velocity relative to the CW frame R in closed
  form.

``benchmarks/ik_compare.py`` builds Pink's model with :func:`build_model`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

__all__ = [
    "DH_A",
    "DH_ALPHA",
    "DH_D",
    "PinArm",
    "RefProcessor",
    "RefSensor",
    "RefServo",
    "RefRailVfdm",
    "RefVfdm",
    "build_model",
    "build_rail_model",
    "deadband",
    "dh_placement",
    "omega_relative",
    "sensor_load_S",
    "virtual_inertias",
    "virtual_model",
]

# --- the UR10e ------------------------------------------------------------------------------

# Official UR10e DH table (Universal Robots, "DH parameters for calculations of kinematics
# and dynamics"), typed in here independently of app.sim.ur10e.
DH_D = (0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655)
DH_A = (0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
JOINT_NAMES = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
    "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)
# Data sheet: ±360° on every joint, 120 °/s base and shoulder, 180 °/s elbow and wrists.
POSITION_LIMIT = 2.0 * math.pi
SPEED_LIMITS = tuple(math.radians(d) for d in (120.0, 120.0, 180.0, 180.0, 180.0, 180.0))
MAX_EFFORT = (330.0, 330.0, 150.0, 56.0, 56.0, 56.0)

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def dh_placement(i: int) -> pin.SE3:
    """``Tz(d_i) Tx(a_i) Rx(alpha_i)`` of DH link i (0-based): the constant part of the
    standard link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``, i.e. the placement of
    joint i+2 in the frame of joint i+1 (of the flange in the frame of joint 6 for i = 5)."""
    c, s = math.cos(DH_ALPHA[i]), math.sin(DH_ALPHA[i])
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return pin.SE3(R, np.array([DH_A[i], 0.0, DH_D[i]]))


def build_model(
    inertias: Sequence[pin.Inertia] | None = None,
    T_F_C: np.ndarray | None = None,
    gravity: bool = True,
) -> pin.Model:
    """Pinocchio model of the UR10e from its DH parameters.

    Six revolute-z joints, joint 1 at the base B; ``inertias[i]`` is the body moved by joint
    i+1, in that joint's frame (default: a nominal 1 kg sphere, kinematics only). Frames:
    ``"flange"`` (DH frame 6 = tool0) on joint 6 and, when ``T_F_C`` is given, ``"tcp"``
    (mockup COM) placed at ``T_F_C`` from the flange. ``gravity=False`` zeroes gravity.
    """
    if inertias is None:
        inertias = [pin.Inertia.FromSphere(1.0, 0.05) for _ in range(6)]
    model = pin.Model()
    model.name = "ur10e"
    placement, parent = pin.SE3.Identity(), 0
    for i in range(6):
        parent = model.addJoint(
            parent, pin.JointModelRZ(), placement, JOINT_NAMES[i],
            np.array([MAX_EFFORT[i]]), np.array([SPEED_LIMITS[i]]),
            np.array([-POSITION_LIMIT]), np.array([POSITION_LIMIT]),
        )
        model.appendBodyToJoint(parent, inertias[i], pin.SE3.Identity())
        placement = dh_placement(i)
    flange = model.addFrame(pin.Frame("flange", parent, placement, pin.FrameType.OP_FRAME))
    if T_F_C is not None:
        T_J6_C = placement.homogeneous @ np.asarray(T_F_C, dtype=float)
        model.addFrame(pin.Frame("tcp", parent, flange, pin.SE3(T_J6_C), pin.FrameType.OP_FRAME))
    if not gravity:
        model.gravity = pin.Motion.Zero()
    return model


def build_rail_model(
    axis_B: np.ndarray,
    inertias: Sequence[pin.Inertia],
    rail_mass: float,
    T_F_C: np.ndarray,
    armature: float = 0.0,
) -> pin.Model:
    """Pinocchio model of a UR10e on a linear rail, no gravity: a prismatic joint along
    ``axis_B`` at the base (its body: a point mass ``rail_mass`` at the origin), then the six
    revolute-z joints of the DH table on it, ``inertias[i]`` on joint i+1; frames
    ``"flange"`` and ``"tcp"``; ``armature`` on the six arm joints only."""
    model = pin.Model()
    model.name = "ur10e_on_rail"
    axis = np.asarray(axis_B, dtype=float)
    parent = model.addJoint(0, pin.JointModelPrismaticUnaligned(axis / np.linalg.norm(axis)),
                            pin.SE3.Identity(), "rail_joint")
    model.appendBodyToJoint(parent, pin.Inertia(rail_mass, np.zeros(3), np.zeros((3, 3))),
                            pin.SE3.Identity())
    placement = pin.SE3.Identity()
    for i in range(6):
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, JOINT_NAMES[i])
        model.appendBodyToJoint(parent, inertias[i], pin.SE3.Identity())
        placement = dh_placement(i)
    flange = model.addFrame(pin.Frame("flange", parent, placement, pin.FrameType.OP_FRAME))
    T_J6_C = placement.homogeneous @ np.asarray(T_F_C, dtype=float)
    model.addFrame(pin.Frame("tcp", parent, flange, pin.SE3(T_J6_C), pin.FrameType.OP_FRAME))
    model.gravity = pin.Motion.Zero()
    model.armature = np.array([0.0] + [float(armature)] * 6)
    return model


def virtual_inertias(cfg, T_F_C: np.ndarray) -> list[pin.Inertia]:
    """Table 1's conditioned inertia: links 1-5 a small mass and inertia at their joint
    origin, link 6 ``m_e`` and ``I_e · I3`` with its centre of mass at the TCP."""
    small = pin.Inertia(cfg.link_mass_kg, np.zeros(3),
                        cfg.link_inertia_ratio * cfg.end_inertia_kgm2 * np.eye(3))
    p_J6_C = (dh_placement(5).homogeneous @ np.asarray(T_F_C, dtype=float))[:3, 3]
    end = pin.Inertia(cfg.end_mass_kg, p_J6_C, cfg.end_inertia_kgm2 * np.eye(3))
    return [small] * 5 + [end]


def virtual_model(cfg, T_F_C: np.ndarray) -> pin.Model:
    """The VFDM's virtual arm (``cfg``: a VfdmConfig): conditioned inertia, the joints'
    armature, no gravity."""
    model = build_model(virtual_inertias(cfg, T_F_C), T_F_C, gravity=False)
    model.armature = np.full(model.nv, float(cfg.joint_armature_kgm2))
    return model


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class PinArm:
    """Pinocchio kinematics and dynamics of one UR10e model (default: kinematics only)."""

    def __init__(self, T_F_C: np.ndarray | None = None, model: pin.Model | None = None):
        self.T_F_C = np.eye(4) if T_F_C is None else np.asarray(T_F_C, dtype=float)
        self.model = build_model(T_F_C=self.T_F_C) if model is None else model
        self.data = self.model.createData()
        self.flange_id = self.model.getFrameId("flange")

    def joint_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R (6, 3, 3), p (6, 3)): every joint's frame in B."""
        pin.forwardKinematics(self.model, self.data, q)
        oMi = self.data.oMi
        return (np.array([oMi[i].rotation for i in range(1, 7)]),
                np.array([oMi[i].translation for i in range(1, 7)]))

    def flange_pose(self, q: np.ndarray) -> np.ndarray:
        """T_B_F."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.updateFramePlacement(self.model, self.data, self.flange_id).homogeneous.copy()

    def tcp_pose(self, q: np.ndarray) -> np.ndarray:
        """T_B_C = T_B_F T_F_C."""
        return self.flange_pose(q) @ self.T_F_C

    def tcp_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Rows [v_C; ω] in base axes: the flange's LOCAL_WORLD_ALIGNED Jacobian with its
        linear rows shifted to the TCP, ``v_C = v_F + ω × p_FC = v_F − [p_FC]× ω``."""
        J = pin.computeFrameJacobian(self.model, self.data, np.asarray(q, dtype=float),
                                     self.flange_id, _LWA).copy()
        p_FC_B = self.data.oMf[self.flange_id].rotation @ self.T_F_C[:3, 3]
        J[:3] -= skew(p_FC_B) @ J[3:]
        return J

    def frame_jacobian(self, q: np.ndarray, name: str) -> np.ndarray:
        """LOCAL_WORLD_ALIGNED Jacobian of a model frame (``"tcp"`` of a model with one)."""
        fid = self.model.getFrameId(name)
        return pin.computeFrameJacobian(self.model, self.data, np.asarray(q, dtype=float),
                                        fid, _LWA).copy()

    def inertia(self, q: np.ndarray) -> np.ndarray:
        """H(q) by CRBA (Pinocchio fills the upper triangle; symmetrised here)."""
        H = pin.crba(self.model, self.data, np.asarray(q, dtype=float))
        return np.triu(H) + np.triu(H, 1).T

    def aba_qdd(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """ABA at zero velocity: ``H⁻¹ (τ − g(q))``, so ``H⁻¹ τ`` on a model without gravity."""
        return pin.aba(self.model, self.data, np.asarray(q, dtype=float), np.zeros(6),
                       np.asarray(tau, dtype=float)).copy()


# --- VFDM -----------------------------------------------------------------------------------


def clamp_norm(v: np.ndarray, max_norm: float) -> np.ndarray:
    """v scaled down (in place) to a norm of at most max_norm."""
    n = math.sqrt(float(v @ v))
    if n > max_norm:
        v *= max_norm / n
    return v


class RefVfdm:
    """The VFDM solver (paper Eqs. 9-13) on the Pinocchio virtual model, one internal step
    at a time: the clamped pose error ``e = [p* − p; log(R* Rᵀ)]``, ``f = K_P e + K_D ė``
    (ė by the difference of successive errors over the internal step), ``τ = Jᵀ f``,
    ``q̈ = H⁻¹ τ`` (ABA at zero velocity), semi-implicit Euler with the velocity damping (or
    a reset to rest each cycle), and the joint-limit clamp."""

    def __init__(self, cfg, T_F_C: np.ndarray, q0: np.ndarray):
        self.cfg = cfg
        self.arm = PinArm(T_F_C, virtual_model(cfg, T_F_C))
        self.tcp_id = self.arm.model.getFrameId("tcp")
        s = cfg.error_scale
        self.kp = s * np.array([cfg.kp_lin] * 3 + [cfg.kp_rot] * 3)
        self.kd = s * np.array([cfg.kd_lin] * 3 + [cfg.kd_rot] * 3)
        self.keep = 1.0 - cfg.damping if cfg.velocity_mode == "damped" else 1.0
        self.reset(q0)

    def reset(self, q: np.ndarray) -> None:
        self.q = np.clip(np.array(q, dtype=float), -POSITION_LIMIT, POSITION_LIMIT)
        self.qd = np.zeros(6)
        self.e_prev: np.ndarray | None = None
        self.last_error = np.zeros(6)
        self.target_prev: np.ndarray | None = None
        self.ff = np.zeros(6)

    def solve(self, T_target: np.ndarray) -> np.ndarray:
        """One control cycle: ``iterations`` internal steps; the joint set-points.

        Feedforward (``velocity_feedforward``, damped mode): the target's velocity over the
        cycle's virtual time ``V = Δ / (N h)`` (Δ: the target's displacement and rotation
        vector since the last cycle) times the damping's drag coefficient per unit
        inertia, ``(1 − k) / (k h)`` (a joint moving at q̇ keeps q̇ when q̈ h k = q̇ (1 − k)),
        times Λ = diag(m_e, I_e): a constant wrench added to Eq. 13's for the cycle."""
        cfg = self.cfg
        if cfg.velocity_mode == "reset":
            self.qd[:] = 0.0
        self.ff = np.zeros(6)
        if cfg.velocity_feedforward and self.keep < 1.0 and self.target_prev is not None:
            P = self.target_prev
            delta = np.concatenate([
                clamp_norm(T_target[:3, 3] - P[:3, 3], cfg.max_error_lin_m),
                clamp_norm(pin.log3(T_target[:3, :3] @ P[:3, :3].T), cfg.max_error_rot_rad)])
            h = cfg.internal_dt_s
            inertia = np.array([cfg.end_mass_kg] * 3 + [cfg.end_inertia_kgm2] * 3)
            self.ff = inertia * delta / (cfg.iterations * h) * (1 - self.keep) / (self.keep * h)
        self.target_prev = np.array(T_target, dtype=float)
        for _ in range(cfg.iterations):
            self.step(T_target)
        return self.q.copy()

    def wrench(self, model, data, T_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the TCP's Jacobian (LOCAL_WORLD_ALIGNED), Eq. 13's f on the clamped pose error,
        with the D term once a previous error is held) at self.q; keeps the error."""
        cfg, h = self.cfg, self.cfg.internal_dt_s
        pin.computeJointJacobians(model, data, self.q)
        oMc = pin.updateFramePlacement(model, data, self.tcp_id)
        J = pin.getFrameJacobian(model, data, self.tcp_id, _LWA)
        e = np.empty(6)
        e[:3] = clamp_norm(T_target[:3, 3] - oMc.translation, cfg.max_error_lin_m)
        e[3:] = clamp_norm(pin.log3(T_target[:3, :3] @ oMc.rotation.T), cfg.max_error_rot_rad)
        f = self.kp * e + self.ff
        if self.e_prev is not None:
            f += self.kd * (e - self.e_prev) / h
        self.e_prev, self.last_error = e, e.copy()
        return J, f

    def step(self, T_target: np.ndarray) -> None:
        h = self.cfg.internal_dt_s
        J, f = self.wrench(self.arm.model, self.arm.data, T_target)
        qdd = self.arm.aba_qdd(self.q, J.T @ f)
        self.qd = (self.qd + h * qdd) * self.keep
        self.q = self.q + h * self.qd
        hit = np.abs(self.q) > POSITION_LIMIT
        self.q = np.clip(self.q, -POSITION_LIMIT, POSITION_LIMIT)
        self.qd[hit] = 0.0


class RefRailVfdm(RefVfdm):
    """:class:`RefVfdm` on the UR10e on a rail (:func:`build_rail_model`, q = [s, q1 … q6]),
    plus the null-space posture term written with the dynamically consistent projector,
    ``q̈_p = H⁻¹ Nᵀ τ_p``, ``N = I − H⁻¹ Jᵀ Λ J``, ``Λ = (J H⁻¹ Jᵀ)⁻¹``, ``τ_p = −K [0; q_arm −
    posture]`` (away from singularities only: it inverts J H⁻¹ Jᵀ), and the carriage
    clamped to ``travel_m`` as the arm's joints to ±2π. No speed or acceleration limits."""

    def __init__(self, cfg, rail, T_F_C: np.ndarray, q0: np.ndarray, posture: np.ndarray):
        self.cfg, self.rail = cfg, rail
        axis = np.asarray(rail.axis_W, dtype=float)  # (the base at the identity: W = B0)
        self.model = build_rail_model(axis, virtual_inertias(cfg, T_F_C), rail.virtual_mass_kg,
                                      T_F_C, cfg.joint_armature_kgm2)
        self.data = self.model.createData()
        self.tcp_id = self.model.getFrameId("tcp")
        self.posture = np.asarray(posture, dtype=float)
        s = cfg.error_scale
        self.kp = s * np.array([cfg.kp_lin] * 3 + [cfg.kp_rot] * 3)
        self.kd = s * np.array([cfg.kd_lin] * 3 + [cfg.kd_rot] * 3)
        self.keep = 1.0 - cfg.damping if cfg.velocity_mode == "damped" else 1.0
        self.lo = np.array([rail.travel_m[0]] + [-POSITION_LIMIT] * 6)
        self.hi = np.array([rail.travel_m[1]] + [POSITION_LIMIT] * 6)
        self.reset(q0)

    def reset(self, q: np.ndarray) -> None:
        super().reset(q)
        self.q = np.clip(np.array(q, dtype=float), self.lo, self.hi)
        self.qd = np.zeros(7)

    def step(self, T_target: np.ndarray) -> None:
        model, data, h = self.model, self.data, self.cfg.internal_dt_s
        J, f = self.wrench(model, data, T_target)
        zero = np.zeros(7)
        qdd = pin.aba(model, data, self.q, zero, J.T @ f).copy()
        k = self.rail.posture_stiffness_Nm_per_rad
        if k:
            H = pin.crba(model, data, self.q)
            H = np.triu(H) + np.triu(H, 1).T
            Hi = np.linalg.inv(H)
            N = np.eye(7) - Hi @ J.T @ np.linalg.inv(J @ Hi @ J.T) @ J
            qdd += Hi @ N.T @ np.concatenate([[0.0], -k * (self.q[1:] - self.posture)])
        self.qd = (self.qd + h * qdd) * self.keep
        self.q = self.q + h * self.qd
        hit = (self.q < self.lo) | (self.q > self.hi)
        self.q = np.clip(self.q, self.lo, self.hi)
        self.qd[hit] = 0.0


# --- servo ------------------------------------------------------------------------------------


class RefServo:
    """The simulated UR10e position servo, one cycle per :meth:`step`.

    1. transport delay: a ring of ``delay_cycles`` set-points in flight;
    2. the controller's checks, first violation wins: joint j beyond ±position limit (or
       NaN), implied speed ``|sp − last accepted sp| / dt`` beyond joint j's limit, TCP
       outside the safety box (Pinocchio FK);
    3. not stopped: ``q̈ = ω² (sp − q) − 2ζω q̇``; stopped: brake at the acceleration limit
       without passing through zero; then saturate q̈ and q̇, semi-implicit Euler.

    ``box``: ``(p_min_W, p_max_W, T_W_B, T_F_C)`` or None.
    """

    def __init__(self, cfg, dt: float, q0: np.ndarray, box=None):
        self.cfg, self.dt = cfg, float(dt)
        w = 2.0 * math.pi * cfg.bandwidth_hz
        self.w2, self.two_zw = w * w, 2.0 * cfg.damping_ratio * w
        self.speed = np.array(cfg.speed_limits_radps)
        self.accel = cfg.accel_limit_radps2
        self.box = box
        if box is not None:
            self.arm = PinArm(box[3])
        self.reset(q0)

    def reset(self, q: np.ndarray | None = None) -> None:
        q = self.q if q is None else np.array(q, dtype=float)
        self.q, self.qd, self.qdd = q.copy(), np.zeros(6), np.zeros(6)
        self.stopped, self.reason = False, ""
        self.ring = [q.copy() for _ in range(self.cfg.delay_cycles)]
        self.sp_prev = q.copy()

    def tcp_position_W(self, q: np.ndarray) -> np.ndarray:
        return (self.box[2] @ self.arm.tcp_pose(q))[:3, 3]

    def check(self, sp: np.ndarray) -> str:
        for j in range(6):
            if not abs(sp[j]) <= self.cfg.position_limit_rad:
                return f"joint {j + 1} position limit"
        speed = np.abs(sp - self.sp_prev) / self.dt
        for j in range(6):
            if speed[j] > self.speed[j] * (1.0 + 1e-9):
                return f"joint {j + 1} speed limit"
        if self.box is not None:
            p = self.tcp_position_W(sp)
            if not (np.all(p >= self.box[0]) and np.all(p <= self.box[1])):
                return "TCP left safety volume"
        return ""

    def step(self, sp_in: np.ndarray) -> None:
        sp = np.array(sp_in, dtype=float)
        if self.ring:
            self.ring.append(sp)
            sp = self.ring.pop(0)
        if not self.stopped:
            self.reason = self.check(sp)
            self.stopped = bool(self.reason)
            if not self.stopped:
                self.sp_prev = sp
        if self.stopped:
            qdd = -np.sign(self.qd) * np.minimum(self.accel, np.abs(self.qd) / self.dt)
        else:
            qdd = self.w2 * (sp - self.q) - self.two_zw * self.qd
        qd = np.clip(self.qd + self.dt * np.clip(qdd, -self.accel, self.accel),
                     -self.speed, self.speed)
        self.qdd = (qd - self.qd) / self.dt
        self.qd = qd
        self.q = self.q + self.dt * qd


# --- F/T sensor and the processing chain ------------------------------------------------------


def sensor_load_S(wrench_ext_W, T_W_C, T_W_F, mass, gravity_W, accel_W=None) -> np.ndarray:
    """Noise-free load of a rigidly mounted mockup on the flange sensor, in S (= F).

    Newton on the mockup, ``m a = F_ext + m g + F_sensor→mockup``, gives the force on the
    sensor ``f = F_ext + m (g − a)``; its moment about the sensor origin is ``τ_ext,C +
    r_FC × f``.
    """
    g_eff = np.asarray(gravity_W, dtype=float)
    if accel_W is not None:
        g_eff = g_eff - np.asarray(accel_W, dtype=float)
    f_W = np.asarray(wrench_ext_W[:3], dtype=float) + mass * g_eff
    t_W = np.asarray(wrench_ext_W[3:], dtype=float) + np.cross(T_W_C[:3, 3] - T_W_F[:3, 3], f_W)
    R_F_W = T_W_F[:3, :3].T
    return np.concatenate([R_F_W @ f_W, R_F_W @ t_W])


class RefSensor:
    """The flange F/T sensor: ``clip(load + bias + σ·N(0, 1), ±range)`` per component, then
    the reading taken ``delay_cycles`` calls earlier (the first reading until then). One
    ``rng.standard_normal(6)`` per call."""

    def __init__(self, config, mass: float, gravity_W: np.ndarray, rng: np.random.Generator):
        self.mass, self.gravity_W, self.rng = float(mass), np.asarray(gravity_W), rng
        self.bias = np.array([*config.bias_force_N, *config.bias_torque_Nm])
        self.std = np.array([config.noise_force_N] * 3 + [config.noise_torque_Nm] * 3)
        self.range = np.array([config.range_force_N] * 3 + [config.range_torque_Nm] * 3)
        self.delay_cycles = config.delay_cycles
        self.history: list[np.ndarray] = []

    def reset(self) -> None:
        """Forget past readings: the next one fills the delay line again."""
        self.history = []

    def read_now(self, load_S: np.ndarray) -> np.ndarray:
        noisy = load_S + self.bias + self.std * self.rng.standard_normal(6)
        return np.clip(noisy, -self.range, self.range)

    def delay(self, reading: np.ndarray) -> np.ndarray:
        if not self.history:
            self.history = [reading] * (self.delay_cycles + 1)
        else:
            self.history = self.history[1:] + [reading]
        return self.history[0].copy()

    def measure(self, wrench_ext_W, T_W_C, T_W_F, accel_W=None) -> np.ndarray:
        load = sensor_load_S(wrench_ext_W, T_W_C, T_W_F, self.mass, self.gravity_W, accel_W)
        return self.delay(self.read_now(load))


def deadband(v: np.ndarray, threshold: float, mode: str) -> np.ndarray:
    """Deadband on the magnitude of a 3-vector, direction kept: 0 at or below the threshold;
    above it 'hard' passes v unchanged, 'soft' shrinks its magnitude by the threshold."""
    n = math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
    if n <= threshold:
        return np.zeros(3)
    return v * ((n - threshold) / n) if mode == "soft" else v.copy()


class RefProcessor:
    """The lab's processing chain: bias removal, payload compensation ``m g`` and (optional)
    inertial compensation ``−m a`` in S with the moment ``c × f`` → first-order low-pass →
    moment shifted from S to the COM by the filtered force → deadbands of the force and of
    the torque about the COM → force into R, torque into the body axes. Poses and
    acceleration are those of the cycle the reading was taken in (``delay_cycles`` ago).
    ``calibration``: an app.sim.ft_sensor.Calibration (bias, mass, COM in F).
    """

    def __init__(self, config, alpha: float, gravity_W: np.ndarray, calibration,
                 delay_cycles: int = 0):
        self.config, self.alpha, self.gravity_W = config, alpha, np.asarray(gravity_W)
        self.cal = calibration
        self.delay_cycles = delay_cycles
        self.reset()

    def reset(self) -> None:
        self.state = np.zeros(6)
        self.past = []

    def compensate(self, wrench_S, R_W_F, accel_W) -> np.ndarray:
        cfg, cal = self.config, self.cal
        w = np.asarray(wrench_S, dtype=float) - cal.bias_S
        g_eff = self.gravity_W if cfg.payload_compensation else np.zeros(3)
        if cfg.inertial_compensation:
            g_eff = g_eff - np.asarray(accel_W, dtype=float)
        load_F = R_W_F.T @ (cal.mass_kg * g_eff)
        w[:3] -= load_F
        w[3:] -= np.cross(cal.com_F_m, load_F)
        return w

    def deadbands(self) -> tuple[float, float]:
        """(force, torque) deadbands: the configured ones, or deadband_noise_sigmas times
        the largest standard deviation of the calibrated noise through the low-pass (a
        first-order filter passes α / (2 − α) of white noise's variance), if larger."""
        cfg, gain = self.config, self.alpha / (2.0 - self.alpha)
        sd = [np.sqrt(np.max(np.linalg.eigvalsh(c)) * gain)
              for c in (self.cal.force_noise_cov_S, self.cal.torque_noise_cov_S)]
        return (max(cfg.deadband_force_N, cfg.deadband_noise_sigmas * sd[0]),
                max(cfg.deadband_torque_Nm, cfg.deadband_noise_sigmas * sd[1]))

    def filter(self, w: np.ndarray) -> np.ndarray:
        self.state = self.state + self.alpha * (w - self.state)
        return self.state.copy()

    def process(self, wrench_S, T_W_F, T_W_C, R_W_R, accel_W=None, gate_open=False):
        """(force in R, torque about the COM in body axes, processed wrench in S axes with
        the moment about the COM)."""
        self.past.append((T_W_F, T_W_C, np.zeros(3) if accel_W is None else accel_W))
        T_W_F, T_W_C, accel_W = self.past[max(0, len(self.past) - 1 - self.delay_cycles)]
        cfg, R_W_F = self.config, T_W_F[:3, :3]
        db_f, db_t = (0.0, 0.0) if gate_open else self.deadbands()
        w = self.filter(self.compensate(wrench_S, R_W_F, accel_W))
        r_FC_S = R_W_F.T @ (T_W_C[:3, 3] - T_W_F[:3, 3])
        t_C_S = deadband(w[3:] - np.cross(r_FC_S, w[:3]), db_t, cfg.deadband_mode)
        f_S = deadband(w[:3], db_f, cfg.deadband_mode)
        return (R_W_R.T @ (R_W_F @ f_S), T_W_C[:3, :3].T @ (R_W_F @ t_C_S),
                np.concatenate([f_S, t_C_S]))


# --- ODS ----------------------------------------------------------------------------------------


def omega_relative(attitude_wxyz: np.ndarray, omega_inertial: np.ndarray,
                   orbit_rate: float) -> np.ndarray:
    """Body-axes angular velocity relative to R: ``ω − Ω R_R_Bᵀ ẑ`` (R turns at Ω about ẑ)."""
    w, x, y, z = attitude_wxyz
    R_R_B = pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()
    return np.asarray(omega_inertial, dtype=float) - orbit_rate * R_R_B.T @ np.array([0, 0, 1.0])
