"""Loop speed benchmark: per-stage cycle cost, real-time factor, VFDM cost per arm.

    .venv/bin/python -m benchmarks.loop_speed            # full
    .venv/bin/python -m benchmarks.loop_speed --quick    # small sizes (smoke test)

Stages are timed by wrapping the very objects the loop calls (instance attributes shadow
the methods, so ``Emulator.step`` runs unchanged); "bookkeeping" is the rest of the cycle
(command queue, hand wrenches, target transforms, Python glue).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np

from app.headless import run_scenario
from app.scenarios import load_scenario
from app.sim import vfdm as vfdm_module
from app.sim.loop import Emulator
from app.sim.rotations import make_transform, rotvec_to_matrix
from app.sim.ur10e import T_F_C_from_config
from app.sim.vfdm import Vfdm

VFDM_TARGET_US = 100.0
RTF_TARGET = 10.0


def _timed(fn, acc: dict, key: str):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += time.perf_counter_ns() - t0

    return wrapper


def stage_breakdown(scenario: str, cycles: int) -> tuple[dict[str, float], float]:
    """Mean µs per cycle of each stage (hil), over `cycles` cycles after prepare()."""
    em = Emulator(load_scenario(scenario), mode="hil")
    em.prepare()
    acc: dict[str, int] = defaultdict(int)
    em.ods.step = _timed(em.ods.step, acc, "ODS step")
    em.contact.compute = _timed(em.contact.compute, acc, "contact")
    em._record = _timed(em._record, acc, "telemetry (_record)")
    for arm in em.arms:
        arm.mockup_state_W = _timed(arm.mockup_state_W, acc, "arm FK + twist")
        arm.sensor.measure = _timed(arm.sensor.measure, acc, "F/T chain (sensor+processing)")
        arm.processor.process = _timed(
            arm.processor.process, acc, "F/T chain (sensor+processing)"
        )
        arm.vfdm.solve = _timed(arm.vfdm.solve, acc, f"VFDM arm {arm.index + 1}")
        arm.servo.step = _timed(arm.servo.step, acc, f"servo arm {arm.index + 1}")
    em.cycle_time_ns.clear()
    n = 0
    for _ in range(cycles):
        if em.status != "running":
            break
        em.step()
        n += 1
    total_ns = float(np.sum(em.cycle_time_ns))
    out = {k: v / n / 1e3 for k, v in acc.items()}
    out["bookkeeping (rest)"] = total_ns / n / 1e3 - sum(out.values())
    return out, total_ns / n / 1e3


def realtime_factor(scenario: str, duration_s: float | None) -> tuple[float, float, float]:
    """(realtime_factor from run_scenario's metrics, loop-only factor, simulated s)."""
    cfg = load_scenario(scenario)
    res = run_scenario(cfg, mode="hil", duration_s=duration_s)
    em = res.emulator
    sim_s = em.cycles * em.dt_s
    loop_s = float(np.sum(em.cycle_time_ns)) / 1e9
    return float(res.metrics["realtime_factor"]), sim_s / loop_s, sim_s


def vfdm_cost(iterations: int, cycles: int, kernel: bool) -> float:
    """Mean µs per VFDM solve (one arm, one cycle) tracking a moving target.

    kernel=False forces the Python/pinocchio reference path (``Vfdm.use_kernel``).
    """
    cfg = load_scenario("collision")
    robot = cfg.robots[1]
    vcfg = cfg.vfdm.model_copy(update={"iterations": iterations})
    T_F_C = T_F_C_from_config(robot)
    q0 = np.array(robot.q_home_rad)
    v = Vfdm(vcfg, T_F_C, q0)
    v.use_kernel = kernel and vfdm_module._solve_compiled is not None
    T0 = v.tcp_pose().copy()
    targets = []
    for k in range(cycles):
        s = k / 500.0
        T = T0 @ make_transform(rotvec_to_matrix(np.array([0.0, 0.0, 0.1 * s])), np.zeros(3))
        T[:3, 3] = T0[:3, 3] + np.array([0.05 * np.sin(s), 0.03 * s, 0.0])
        targets.append(T)
    v.solve(targets[0])  # warm-up (and JIT compile, if any)
    t0 = time.perf_counter_ns()
    for T in targets:
        v.solve(T)
    return (time.perf_counter_ns() - t0) / cycles / 1e3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument("--cycles", type=int, default=None, help="cycles for the breakdown")
    ap.add_argument("--no-kernel", action="store_true",
                    help="loop and RTF with the Python VFDM path (numba kernel off)")
    args = ap.parse_args(argv)
    if args.no_kernel:
        vfdm_module._solve_compiled = None
    print(f"VFDM path in the loop: {'kernel' if vfdm_module._solve_compiled else 'Python'}\n")
    cycles = args.cycles or (300 if args.quick else 3000)
    duration = 1.0 if args.quick else None
    vfdm_cycles = 100 if args.quick else 2000

    print(f"## Cycle breakdown: collision, hil, {cycles} cycles after prepare()\n")
    stages, total = stage_breakdown("collision", cycles)
    print("| stage | µs / cycle | share |")
    print("|---|---:|---:|")
    for k, v in stages.items():
        print(f"| {k} | {v:.1f} | {100 * v / total:.0f}% |")
    print(f"| **total cycle** | **{total:.1f}** | 100% |")
    print(f"\nloop-only real-time factor from this: {2000.0 / total:.1f}x (cycle = 2000 µs)\n")

    print("## Real-time factor, headless hil (run_scenario)\n")
    print("| scenario | simulated s | realtime_factor (metrics, incl. prepare) | loop only |")
    print("|---|---:|---:|---:|")
    rtf = {}
    for name in ("collision", "free-floating"):
        r_metrics, r_loop, sim_s = realtime_factor(name, duration)
        rtf[name] = r_metrics
        print(f"| {name} | {sim_s:.1f} | {r_metrics:.2f} | {r_loop:.2f} |")

    print("\n## VFDM cost per arm per cycle (same run: Python reference vs compiled kernel)\n")
    have_kernel = vfdm_module._solve_compiled is not None
    print("| iterations | Python µs / solve | kernel µs / solve | speed-up |")
    print("|---:|---:|---:|---:|")
    cost, kernel = {}, {}
    for it in (1, 10, 50):
        n_c = vfdm_cycles if it < 50 else max(50, vfdm_cycles // 4)
        cost[it] = vfdm_cost(it, n_c, kernel=False)
        if have_kernel:
            kernel[it] = vfdm_cost(it, n_c, kernel=True)
            print(f"| {it} | {cost[it]:.1f} | {kernel[it]:.1f} | {cost[it] / kernel[it]:.1f}x |")
        else:
            print(f"| {it} | {cost[it]:.1f} | n/a (kernel off or numba missing) | - |")

    print("\n## Targets\n")
    best = kernel.get(10, cost[10])
    ok_v = best <= VFDM_TARGET_US
    print(f"- VFDM <= {VFDM_TARGET_US:.0f} µs/arm/cycle at 10 iterations "
          f"({'kernel' if kernel else 'Python'}): {best:.1f} µs -> {'MET' if ok_v else 'NOT MET'}"
          f" (Python reference path: {cost[10]:.1f} µs)")
    ok_r = rtf["collision"] >= RTF_TARGET
    print(f"- collision hil realtime_factor >= {RTF_TARGET:.0f}: "
          f"{rtf['collision']:.2f} -> {'MET' if ok_r else 'NOT MET'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
