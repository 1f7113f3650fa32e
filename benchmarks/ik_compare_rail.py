"""The 7-joint chain (a UR10e on a rail): VFDM with the posture term vs damped least squares.

    .venv/bin/python -m benchmarks.ik_compare_rail            # full
    .venv/bin/python -m benchmarks.ik_compare_rail --quick    # short paths (smoke test)

The paths are benchmarks/ik_compare.py's singular paths of the floor arm, with a rail beside
them along the base's x axis (RailConfig defaults: 1 m/s, 1 m/s², a 10 Hz drive with
velocity feedforward, one cycle of delay), plus a 1.5 m ramp along the rail that no fixed
arm could follow. Every method drives the same servos (the arm's UR10eServo, default
ServoConfig, 500 Hz, no safety box, and the carriage's RailServo) with one solve per cycle;
the errors are of the ACTUAL TCP (both servos' state) against the target. A protective
stop of either servo ends that run.

Methods: the app's RailVfdm (Eq. 10 on the chain, the null-space posture term, the limits
held in its set-points); DLS on the 6x7 chain Jacobian (λ = 0.05, the 6-joint baseline's),
``dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`` (its minimum-norm step weighs the rail's metres against the
arm's radians; no posture term), and DLS with the same posture term added in J's null
space (``(I − J⁺ J) k (q* − q)`` with the damped inverse), the usual redundancy
resolution.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from app.config import RailConfig, ServoConfig, VfdmConfig
from app.sim.rail import chain_jacobian, chain_tcp_pose, rail_arm
from app.sim.rail_servo import RailServo
from app.sim.rail_vfdm import RailVfdm
from app.sim.servo import UR10eServo
from app.sim.ur10e import SPEED_LIMITS_RADPS, tcp_pose_B
from app.sim.vfdm import pose_error
from benchmarks.ik_compare import DT_S, singular_paths, wrist_measure

AXIS_B = np.array([1.0, 0.0, 0.0])
T_F_C = np.eye(4)
T_F_C[2, 3] = 0.07


class ChainDLS:
    """DLS on the chain's 6x7 Jacobian, optionally with a null-space posture term."""

    def __init__(self, q0: np.ndarray, posture: np.ndarray | None = None,
                 damping: float = 0.05, gain: float = 0.02) -> None:
        self.arm = rail_arm(VfdmConfig(), T_F_C, AXIS_B, 1.0)
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
    T0 = tcp_pose_B(q_arm, T_F_C)
    s = 0.5 * (1 - np.cos(np.pi * np.linspace(0, 1, n)))
    s = np.concatenate([s, s[::-1]])
    out = np.repeat(T0[None], len(s), axis=0)
    out[:, :3, 3] += 1.5 * s[:, None] * AXIS_B
    return out


def run(solver, q0: np.ndarray, targets: np.ndarray, posture: np.ndarray) -> dict:
    rail = RailConfig(travel_m=(-2.0, 2.0))
    arm_servo = UR10eServo(ServoConfig(), DT_S, q0[1:], safety=None)
    rail_servo = RailServo(rail, DT_S, q0[0])
    model = rail_arm(VfdmConfig(), T_F_C, AXIS_B, 1.0)
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short paths (smoke test)")
    args = ap.parse_args(argv)
    n = 1000 if args.quick else 2000
    cases = [(label, T, np.concatenate([[0.0], q0]))
             for label, T, q0, _ in singular_paths(T_F_C, n)]
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
            "VFDM + posture (rail)": RailVfdm(VfdmConfig(), rail, np.eye(4), T_F_C, q0,
                                              posture),
            "DLS 7-joint (λ=0.05)": ChainDLS(q0),
            "DLS 7-joint + posture": ChainDLS(q0, posture),
        }
        for name, solver in methods.items():
            r = run(solver, q0, T, posture)
            stop = f"at {r['cycles']}/{r['of']}: {r['stop']}" if r["stop"] else "none"
            print(f"| {label} | {name} | {stop} | {r['pos_max_mm']:.2f} / "
                  f"{r['pos_rms_mm']:.2f} | {r['dev_max']:.3f} | {r['travel_m']:.3f} "
                  f"| {r['qd_peak']:.2f} | {r['us']:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
