"""VFDM vs differential IK (pseudo-inverse, DLS, Jacobian transpose, Pink) on one UR10e.

    .venv/bin/python -m benchmarks.ik_compare            # full
    .venv/bin/python -m benchmarks.ik_compare --quick    # short trajectories (smoke test)
    .venv/bin/python -m benchmarks.ik_compare --rail     # the 7-joint chain's table alone

Every method drives the same simulated UR10e (UR10eServo, default ServoConfig, 500 Hz,
1-cycle delay, no safety box) with one solve per cycle. Tracking errors
are of the ACTUAL (servo) TCP against the target, so they include the servo's lag. A
protective stop ends that run (the errors are then over the cycles before the stop).

The last table is the 7-joint chain (a UR10e on a rail): the singular paths of the floor
arm with a rail beside them along the base's x axis (RailConfig defaults: 1 m/s, 1 m/s², a
10 Hz drive with velocity feedforward, one cycle of delay), plus a 1.5 m ramp along the
rail that no fixed arm could follow. Every method drives the same servos (the arm's
UR10eServo and the carriage's RailServo); the errors are of the ACTUAL TCP (both servos'
state) against the target; a protective stop of either servo ends that run. Methods: the
app's RailVfdm (Eq. 10 on the chain, the null-space posture term, the limits held in its
set-points); DLS on the 6x7 chain Jacobian (λ = 0.05, the 6-joint baseline's),
``dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`` (its minimum-norm step weighs the rail's metres against the
arm's radians; no posture term), and DLS with the same posture term added in J's null
space (``(I − J⁺ J) k (q* − q)`` with the damped inverse), the usual redundancy
resolution.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from app.config import RailConfig, ServoConfig, VfdmConfig
from app.runs.headless import run_scenario
from app.scenarios import load_scenario
from app.sim.loop import Emulator
from app.sim.rail import chain_jacobian, chain_tcp_pose, rail_arm
from app.sim.rail_servo import RailServo
from app.sim.rail_vfdm import RailVfdm
from app.sim.rotations import invert_transform, make_transform, quat_to_matrix
from app.sim.servo import UR10eServo
from app.sim.ur10e import (
    DH_D_M,
    SPEED_LIMITS_RADPS,
    T_F_C_from_config,
    fk_joints,
    joint_placements,
    tcp_pose_B,
)
from app.sim.vfdm import Vfdm, pose_error
from benchmarks.baselines import DampedLeastSquaresIK, JacobianTransposeIK, PseudoInverseIK

RATE_HZ = 500.0
DT_S = 1.0 / RATE_HZ


# --- Pink (optional) --------------------------------------------------------------------


def pink_factory():
    """A factory for a Pink solver with the Vfdm interface, or (None, reason)."""
    try:
        import pink
        import pinocchio as pin
        import qpsolvers
        from pink.tasks import FrameTask

        from tests.oracle import build_model  # Pink needs a Pinocchio model of the UR10e
    except Exception as exc:  # noqa: BLE001
        return None, f"import failed: {exc!r}"
    solver = next((s for s in ("daqp", "quadprog", "proxqp") if s in qpsolvers.available_solvers),
                  None)
    if solver is None:
        return None, "no QP backend (daqp/quadprog/proxsuite) installed"

    class PinkIK:
        """One Pink ``solve_ik`` per cycle (frame task on the TCP, velocity + position limits)."""

        def __init__(self, T_F_C, q0_rad):
            self.model = build_model(T_F_C=np.asarray(T_F_C, dtype=float))
            self.data = self.model.createData()
            self.task = FrameTask("tcp", position_cost=1.0, orientation_cost=1.0)
            self.reset(q0_rad)

        def reset(self, q_rad):
            self.q_rad = np.array(q_rad, dtype=float)

        def solve(self, T_B_C_target):
            conf = pink.Configuration(self.model, self.data, self.q_rad)
            self.task.set_target(pin.SE3(T_B_C_target[:3, :3].copy(), T_B_C_target[:3, 3].copy()))
            v = pink.solve_ik(conf, [self.task], DT_S, solver=solver, safety_break=False)
            self.q_rad = pin.integrate(self.model, self.q_rad, v * DT_S)
            return self.q_rad.copy()

    return PinkIK, f"Pink {pink.__version__} + {solver}"


# --- trajectories -----------------------------------------------------------------------


def scenario_targets(scenario, duration_s: float | None) -> list[tuple[str, np.ndarray, object]]:
    """(label, targets (N,4,4) in B, robot config) per arm, from an ideal run's telemetry
    of a scenario (its name, or its configuration)."""
    cfg = load_scenario(scenario) if isinstance(scenario, str) else scenario
    name = cfg.name
    res = run_scenario(cfg, mode="ideal", duration_s=duration_s)
    ideal = res.emulator
    rows, idx = ideal.telemetry.rows(), ideal.telemetry.index
    hil = Emulator(cfg, mode="hil")  # only for its transforms
    out = []
    for arm, robot in zip(hil.arms, cfg.robots, strict=True):
        s = arm.satellite + 1
        p = rows[:, [idx[f"sat{s}_{a}_m"] for a in "xyz"]]
        q = rows[:, [idx[f"sat{s}_{c}"] for c in ("qw", "qx", "qy", "qz")]]
        T_B_W = invert_transform(arm.T_W_B)
        T = np.array([T_B_W @ hil.T_W_R @ make_transform(quat_to_matrix(qi), pi)
                      for pi, qi in zip(p, q, strict=True)])
        out.append((f"{name}/{robot.name}", T, robot))
        if name == "free-floating-scripted":
            break  # all its arms carry the same satellite: one is enough
    return out


def hold(T: np.ndarray, rate_hz: float) -> np.ndarray:
    """Targets sampled at rate_hz and held in between (zero-order hold)."""
    every = int(round(RATE_HZ / rate_hz))
    k = (np.arange(len(T)) // every) * every
    return T[k]


def fk_path(T_F_C, qa, qb, n: int, back: bool = False) -> np.ndarray:
    """TCP poses along a cosine-profiled joint path qa -> qb (-> qa if back)."""
    s = 0.5 * (1 - np.cos(np.pi * np.linspace(0, 1, n)))
    if back:
        s = np.concatenate([s, s[::-1]])
    return np.array([tcp_pose_B(qa + si * (qb - qa), T_F_C) for si in s])


SINGULAR_NEIGHBOURHOOD_RAD = 0.01
"""The singular region: the cycles where the arm's singularity measure is below 10 mrad."""


def wrist_measure(q: np.ndarray) -> float:
    """|sin q5|: zero when the axes of joints 4 and 6 line up (wrist singularity)."""
    return abs(math.sin(q[4]))


def elbow_measure(q: np.ndarray) -> float:
    """|sin q3|: zero with the elbow fully stretched (or folded)."""
    return abs(math.sin(q[2]))


def shoulder_measure(q: np.ndarray) -> float:
    """acos(d4 / r) of the UR's closed-form IK, r the distance of the wrist centre (origin
    of joint 6's frame) from the base axis: zero when the wrist centre is on the cylinder
    of radius d4 about it, where the two shoulder solutions meet (shoulder singularity)."""
    R, p = np.empty((6, 3, 3)), np.empty((6, 3))
    fk_joints(np.asarray(q, dtype=float), *joint_placements(), R, p)
    r = math.hypot(p[5, 0], p[5, 1])
    return math.acos(min(1.0, DH_D_M[3] / r)) if r > 0 else math.pi / 2


def wrist_elbow_measure(q: np.ndarray) -> float:
    return min(wrist_measure(q), elbow_measure(q))


def singular_paths(T_F_C, n: int) -> list[tuple[str, np.ndarray, np.ndarray, object]]:
    """(label, targets, start q, singularity measure) of the floor arm's singular paths."""
    paths = []
    qa = np.array([0.0, -1.6, 1.6, -1.57, -0.4, 0.0])
    qb = np.array([0.3, -1.5, 1.5, -1.3, 0.4, 0.5])  # q5 through 0 at full speed
    paths.append(("singular/wrist q5=0", fk_path(T_F_C, qa, qb, n), qa, wrist_measure))
    qa = np.array([0.0, -1.2, 0.8, -1.2, -1.57, 0.0])
    qb = np.array([0.0, -0.8, 0.0, -0.8, -1.57, 0.0])  # q3 = 0: elbow fully stretched
    paths.append(("singular/elbow stretched", fk_path(T_F_C, qa, qb, n // 2, back=True), qa,
                  elbow_measure))
    # TCP along a line in B passing straight over the base z axis, tool pointing down
    s = 0.5 * (1 - np.cos(np.pi * np.linspace(0, 1, n)))
    R = np.diag([1.0, -1.0, -1.0])
    T = np.array([make_transform(R, np.array([-0.35 + 0.7 * si, -0.174, 0.9])) for si in s])
    q0 = start_q(T[0], T_F_C, np.array([2.5, -1.2, 1.4, -1.8, -1.57, 0.0]))
    paths.append(("singular/shoulder (over base)", T, q0, shoulder_measure))
    # wrist and elbow at once: q5 through 0 at full speed as the elbow stretches to q3 = 0
    s = 0.5 * (1 - np.cos(np.pi * np.linspace(0, 1, n)))
    qa = np.array([0.0, -1.2, 0.8, -1.2, -0.4, 0.0])
    qb = np.array([0.3, -0.8, 0.8, -0.8, 0.4, 0.5])
    qs = qa + s[:, None] * (qb - qa)
    qs[:, 2] = 0.8 * (1.0 - np.sin(np.pi * s))  # 0.8 -> 0 (at s = 0.5) -> 0.8
    T = np.array([tcp_pose_B(q, T_F_C) for q in qs])
    paths.append(("singular/wrist+elbow", T, qs[0], wrist_elbow_measure))
    return paths


def spin_through_wrist(duration_s: float) -> tuple[str, np.ndarray, object]:
    """The free-floating satellite spinning at 0.2 rad/s about its body x axis (no pushes):
    a quarter turn lines the ceiling arm's wrist up (q5 through -π). Targets from the
    ideal run, in the ceiling arm's base frame."""
    base = load_scenario("free-floating")
    sat = base.satellites[0].model_copy(update={"omega_radps": (0.2, 0.0, 0.0)})
    cfg = base.model_copy(update={"pulses": [], "satellites": [sat]})
    (label, T, robot), = scenario_targets(cfg, duration_s)
    return "free-floating spin through the wrist", T, robot


def start_q(T0: np.ndarray, T_F_C, q_guess) -> np.ndarray:
    """A joint start posture at T0 (the VFDM run to convergence, as Emulator.prepare does)."""
    v = Vfdm(load_scenario("collision").vfdm, T_F_C, q_guess, limits=None)
    for _ in range(5000):
        v.solve(T0)
        e = v.last_error
        if np.linalg.norm(e[:3]) < 1e-6 and np.linalg.norm(e[3:]) < 1e-5:
            break
    return v.q_rad.copy()


# --- one run ----------------------------------------------------------------------------


def run_method(solver, T_F_C, q0, targets: np.ndarray, measure=None) -> dict:
    """Drive the servo with `solver` along `targets`; errors of the actual TCP. With a
    singularity `measure` of the actual joints, also the figures of the singular region."""
    solver.reset(q0)
    servo = UR10eServo(ServoConfig(), DT_S, q0, safety=None)
    pos_err, rot_err, qd_frac, qdd, t_ns, sing, sp_err = [], [], [], [], [], [], []
    stop = ""
    for T in targets:
        t0 = time.perf_counter_ns()
        q_sp = solver.solve(T)
        t_ns.append(time.perf_counter_ns() - t0)
        st = servo.step(q_sp)
        if servo.stopped:
            stop = servo.reason
            break
        e = pose_error(T, tcp_pose_B(st.q_rad, T_F_C))
        pos_err.append(np.linalg.norm(e[:3]))
        sp_err.append(np.linalg.norm(pose_error(T, tcp_pose_B(q_sp, T_F_C))[:3]))
        rot_err.append(np.linalg.norm(e[3:]))
        qd_frac.append(np.max(np.abs(st.qd_radps) / SPEED_LIMITS_RADPS))
        qdd.append(st.qdd_radps2.copy())
        if measure is not None:
            sing.append(measure(st.q_rad))
    pos, rot = np.array(pos_err or [np.nan]), np.array(rot_err or [np.nan])
    jerk = np.diff(np.array(qdd), axis=0) / DT_S if len(qdd) > 2 else np.zeros((1, 6))
    out = {
        "pos_max_mm": 1e3 * pos.max(), "pos_rms_mm": 1e3 * np.sqrt(np.mean(pos**2)),
        "rot_max_deg": np.degrees(rot.max()), "rot_rms_deg": np.degrees(np.sqrt(np.mean(rot**2))),
        "qd_peak": max(qd_frac) if qd_frac else np.nan,
        "jerk_rms": float(np.sqrt(np.mean(jerk**2))),
        "stop": stop, "cycles": len(pos_err), "of": len(targets),
        "us": float(np.mean(t_ns)) / 1e3,
    }
    if measure is not None:
        out.update(singular_region(pos, np.array(sing), np.array(sp_err)))
    return out


def singular_region(pos_err_m: np.ndarray, measure: np.ndarray,
                    setpoint_err_m: np.ndarray | None = None) -> dict:
    """Error inside and outside the singular region, closest approach, and the time from
    leaving the region until the position error is back under 1 mm. setpoint_err_m: the
    error of the set-points' own TCP (the solver's part, without the servo's lag)."""
    inside = measure < SINGULAR_NEIGHBOURHOOD_RAD
    out = {"closest_mrad": 1e3 * measure.min() if len(measure) else np.nan,
           "in_max_mm": np.nan, "out_max_mm": np.nan, "recover_ms": None,
           "sp_out_max_mm": np.nan}
    if len(measure) == 0:
        return out
    if (~inside).any():
        out["out_max_mm"] = 1e3 * pos_err_m[~inside].max()
        if setpoint_err_m is not None:
            out["sp_out_max_mm"] = 1e3 * setpoint_err_m[~inside].max()
    if inside.any():
        out["in_max_mm"] = 1e3 * pos_err_m[inside].max()
        last = int(np.nonzero(inside)[0][-1])
        after = np.nonzero(pos_err_m[last + 1:] < 1e-3)[0]
        if pos_err_m[last] < 1e-3:
            out["recover_ms"] = 0.0
        elif len(after):
            out["recover_ms"] = 1e3 * (after[0] + 1) * DT_S
    return out


# --- the 7-joint chain: a UR10e on a rail -------------------------------------------


RAIL_AXIS_B = np.array([1.0, 0.0, 0.0])
RAIL_T_F_C = np.eye(4)  # the floor arm's mockup offset
RAIL_T_F_C[2, 3] = 0.07


class ChainDLS:
    """DLS on the chain's 6x7 Jacobian, optionally with a null-space posture term."""

    def __init__(self, q0: np.ndarray, posture: np.ndarray | None = None,
                 damping: float = 0.05, gain: float = 0.02) -> None:
        self.arm = rail_arm(VfdmConfig(), RAIL_T_F_C, RAIL_AXIS_B, 1.0)
        self.posture, self.damping, self.gain = posture, damping, gain
        self.q = np.array(q0, dtype=float)

    def solve(self, T: np.ndarray) -> np.ndarray:
        J = chain_jacobian(self.arm, self.q)
        e = pose_error(T, chain_tcp_pose(self.arm, self.q))
        J_inv = J.T @ np.linalg.inv(J @ J.T + self.damping**2 * np.eye(6))
        dq = J_inv @ e
        if self.posture is not None:
            pull = np.concatenate([[0.0], self.posture - self.q[1:]])
            dq += (np.eye(7) - J_inv @ J) @ (self.gain * pull)
        self.q = self.q + dq
        return self.q.copy()


def ramp_along_rail(q_arm: np.ndarray, n: int) -> np.ndarray:
    """The TCP at q_arm moved 1.5 m along the rail (cosine profile) and back."""
    T0 = tcp_pose_B(q_arm, RAIL_T_F_C)
    s = 0.5 * (1 - np.cos(np.pi * np.linspace(0, 1, n)))
    s = np.concatenate([s, s[::-1]])
    out = np.repeat(T0[None], len(s), axis=0)
    out[:, :3, 3] += 1.5 * s[:, None] * RAIL_AXIS_B
    return out


def run_rail_method(solver, q0: np.ndarray, targets: np.ndarray, posture: np.ndarray) -> dict:
    rail = RailConfig(travel_m=(-2.0, 2.0))
    arm_servo = UR10eServo(ServoConfig(), DT_S, q0[1:], safety=None)
    rail_servo = RailServo(rail, DT_S, q0[0])
    model = rail_arm(VfdmConfig(), RAIL_T_F_C, RAIL_AXIS_B, 1.0)
    pos, dev, qd, sing, t_ns, travel = [], [], [], [], [], []
    stop = ""
    for T in targets:
        t0 = time.perf_counter_ns()
        q = solver.solve(T)
        t_ns.append(time.perf_counter_ns() - t0)
        rs, st = rail_servo.step(q[0]), arm_servo.step(q[1:])
        if rail_servo.stopped or arm_servo.stopped:
            stop = rs.reason or st.reason
            break
        actual = np.concatenate([[rs.s_m], st.q_rad])
        pos.append(np.linalg.norm(pose_error(T, chain_tcp_pose(model, actual))[:3]))
        dev.append(np.abs(st.q_rad - posture).max())
        qd.append(np.max(np.abs(st.qd_radps) / SPEED_LIMITS_RADPS))
        sing.append(wrist_measure(st.q_rad))
        travel.append(rs.s_m)
    pos = np.array(pos or [np.nan])
    return {"stop": stop, "cycles": len(t_ns) - bool(stop), "of": len(targets),
            "pos_max_mm": 1e3 * pos.max(), "pos_rms_mm": 1e3 * np.sqrt(np.mean(pos**2)),
            "dev_max": max(dev) if dev else np.nan, "qd_peak": max(qd) if qd else np.nan,
            "travel_m": (max(travel) - min(travel)) if travel else 0.0,
            "us": float(np.mean(t_ns)) / 1e3}


def rail_table(n: int) -> None:
    """The 7-joint chain's table: each path (n cycles; the ramp 2n out, 2n back) by
    each method."""
    print("\n## The 7-joint chain: a UR10e on a rail (VFDM + posture vs DLS)\n")
    cases = [(label, T, np.concatenate([[0.0], q0]))
             for label, T, q0, _ in singular_paths(RAIL_T_F_C, n)]
    q_ramp = np.array([0.0, -1.6, 1.6, -1.57, -1.57, 0.0])
    cases.append(("1.5 m along the rail and back", ramp_along_rail(q_ramp, 2 * n),
                  np.concatenate([[0.0], q_ramp])))
    rail = RailConfig(travel_m=(-2.0, 2.0))
    print("| path | method | protective stop | pos err max / RMS [mm] "
          "| posture dev max [rad] | rail travel [m] | peak qd / limit | µs / cycle |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for label, T, q0 in cases:
        posture = q0[1:].copy()
        methods = {
            "VFDM + posture (rail)": RailVfdm(VfdmConfig(), rail, np.eye(4), RAIL_T_F_C, q0,
                                              posture),
            "DLS 7-joint (λ=0.05)": ChainDLS(q0),
            "DLS 7-joint + posture": ChainDLS(q0, posture),
        }
        for name, solver in methods.items():
            r = run_rail_method(solver, q0, T, posture)
            stop = f"at {r['cycles']}/{r['of']}: {r['stop']}" if r["stop"] else "none"
            print(f"| {label} | {name} | {stop} | {r['pos_max_mm']:.2f} / "
                  f"{r['pos_rms_mm']:.2f} | {r['dev_max']:.3f} | {r['travel_m']:.3f} "
                  f"| {r['qd_peak']:.2f} | {r['us']:.0f} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short trajectories (smoke test)")
    ap.add_argument("--rail", action="store_true",
                    help="only the 7-joint chain's table (a UR10e on a rail)")
    args = ap.parse_args(argv)
    if args.rail:
        rail_table(1000 if args.quick else 2000)
        return 0
    duration = 1.0 if args.quick else None
    n_sing = 1000 if args.quick else 2000  # cycles per singular path (2 s quick, 4 s full)

    vcfg = load_scenario("collision").vfdm
    no_ff = vcfg.model_copy(update={"velocity_feedforward": False})
    no_armature = vcfg.model_copy(update={"joint_armature_kgm2": 0.0})
    paper = no_ff.model_copy(update={"joint_armature_kgm2": 0.0})  # Table 1's model alone
    PinkIK, pink_note = pink_factory()  # noqa: N806
    methods = {
        "VFDM": lambda T_F_C, q0: Vfdm(vcfg, T_F_C, q0),
        "VFDM, no feedforward": lambda T_F_C, q0: Vfdm(no_ff, T_F_C, q0),
        "VFDM, no armature": lambda T_F_C, q0: Vfdm(no_armature, T_F_C, q0),
        "VFDM, Table 1 alone (before)": lambda T_F_C, q0: Vfdm(paper, T_F_C, q0, limits=None),
        "pseudo-inverse": lambda T_F_C, q0: PseudoInverseIK(T_F_C, q0),
        "DLS (λ=0.05)": lambda T_F_C, q0: DampedLeastSquaresIK(T_F_C, q0),
        "J transpose (α=0.2)": lambda T_F_C, q0: JacobianTransposeIK(T_F_C, q0),
    }
    if PinkIK is not None:
        methods["Pink"] = PinkIK
        print(f"Pink: {pink_note}")
    else:
        print(f"Pink unavailable: {pink_note}")

    cases = []  # (label, targets, T_F_C, q0)
    for name in ("collision", "free-floating-scripted"):
        for label, T, robot in scenario_targets(name, duration):
            T_F_C = T_F_C_from_config(robot)
            q0 = start_q(T[0], T_F_C, np.array(robot.q_home_rad))
            cases.append((label + " 500 Hz", T, T_F_C, q0))
            for f in (10.0, 2.0):
                cases.append((f"{label} held {f:g} Hz", hold(T, f), T_F_C, q0))

    print("\n## Scenario trajectories\n")
    print("| trajectory | method | pos err max / RMS [mm] | rot err max / RMS [deg] "
          "| peak qd / limit | RMS jerk [rad/s³] | protective stop | µs / cycle |")
    print("|---|---|---:|---:|---:|---:|---|---:|")
    for label, T, T_F_C, q0 in cases:
        for mname, make in methods.items():
            r = run_method(make(T_F_C, q0), T_F_C, q0, T)
            stop = f"at {r['cycles']}/{r['of']}: {r['stop']}" if r["stop"] else "none"
            print(f"| {label} | {mname} | {r['pos_max_mm']:.2f} / {r['pos_rms_mm']:.2f} "
                  f"| {r['rot_max_deg']:.2f} / {r['rot_rms_deg']:.2f} | {r['qd_peak']:.2f} "
                  f"| {r['jerk_rms']:.3g} | {stop} | {r['us']:.0f} |", flush=True)

    singular = []  # (label, targets, T_F_C, q0, measure)
    robot = load_scenario("collision").robots[1]
    T_F_C = T_F_C_from_config(robot)
    for label, T, q0, measure in singular_paths(T_F_C, n_sing):
        singular.append((label, T, T_F_C, q0, measure))
    label, T, robot = spin_through_wrist(3.0 if args.quick else 15.0)
    T_F_C = T_F_C_from_config(robot)
    singular.append((label, T, T_F_C, start_q(T[0], T_F_C, np.array(robot.q_home_rad)),
                     wrist_measure))

    print(f"\n## Singular paths (singular region: measure < "
          f"{1e3 * SINGULAR_NEIGHBOURHOOD_RAD:.0f} mrad)\n")
    print("| path | method | protective stop | peak qd / limit | pos err max / RMS [mm] "
          "| max err outside / inside the region [mm] | set-point err outside [mm] "
          "| closest [mrad] | recovery to < 1 mm [ms] | µs / cycle |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for label, T, T_F_C, q0, measure in singular:
        for mname, make in methods.items():
            r = run_method(make(T_F_C, q0), T_F_C, q0, T, measure)
            stop = f"at {r['cycles']}/{r['of']}: {r['stop']}" if r["stop"] else "none"
            rec = "-" if np.isnan(r["in_max_mm"]) else (
                "never" if r["recover_ms"] is None else f"{r['recover_ms']:.0f}")
            print(f"| {label} | {mname} | {stop} | {r['qd_peak']:.2f} "
                  f"| {r['pos_max_mm']:.2f} / {r['pos_rms_mm']:.2f} "
                  f"| {r['out_max_mm']:.2f} / {r['in_max_mm']:.2f} | {r['sp_out_max_mm']:.2f} "
                  f"| {r['closest_mrad']:.1f} "
                  f"| {rec} | {r['us']:.0f} |", flush=True)
    rail_table(n_sing)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
