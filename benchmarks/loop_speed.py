"""Loop speed benchmark: per-stage cycle cost, Python reference vs compiled, real-time factor.

    .venv/bin/python -m benchmarks.loop_speed               # full
    .venv/bin/python -m benchmarks.loop_speed --quick       # small sizes (smoke test)
    .venv/bin/python -m benchmarks.loop_speed --no-kernel   # Python VFDM in the compiled runs

Every stage of ``Emulator.step`` has a compiled (numba) path next to its Python reference
path, switched by a ``use_kernel`` attribute (``Emulator.set_compiled`` flips them all), and
every table compares the two in the same run. Stages are timed by wrapping the very
objects the loop calls (instance attributes shadow the methods, so ``Emulator.step`` runs
unchanged); "bookkeeping" is the rest of the cycle (command queue, hand wrenches, target
transforms, Python glue).
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
CYCLE_US = 2000.0

SWITCHES = {
    "arm FK + twist (Arm.use_kernel)": lambda em, on: [
        setattr(a, "use_kernel", on) for a in em.arms],
    "F/T chain (sensor, processor .use_kernel)": lambda em, on: [
        setattr(x, "use_kernel", on) for a in em.arms for x in (a.sensor, a.processor)],
    "servo (UR10eServo.use_kernel)": lambda em, on: [
        setattr(a.servo, "use_kernel", on) for a in em.arms],
    "VFDM (Vfdm.use_kernel)": lambda em, on: [
        setattr(a.vfdm, "use_kernel", on and vfdm_module.vfdm_kernel_available())
        for a in em.arms],
    "bookkeeping + telemetry (Emulator, OrbitalSimulator .use_kernel)": lambda em, on: [
        setattr(x, "use_kernel", on) for x in (em, em.ods)],
}
VFDM_SWITCH = "VFDM (Vfdm.use_kernel)"


def _timed(fn, acc: dict, key: str):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += time.perf_counter_ns() - t0

    return wrapper


def _prepared(scenario: str, switches_on: set[str]) -> Emulator:
    """A hil emulator after prepare(), with exactly the named switches on."""
    em = Emulator(load_scenario(scenario), mode="hil")
    for name, switch in SWITCHES.items():
        switch(em, name in switches_on)
    em.prepare()
    em.cycle_time_ns.clear()
    return em


def _interleaved(ems: list[Emulator], cycles: int, chunk: int = 20) -> list[int]:
    """Step the emulators round-robin, `chunk` cycles each in turn, up to `cycles` each,
    so that background load on the (shared) machine falls on all of them alike; returns
    the number of cycles each ran."""
    done = [0] * len(ems)
    active = set(range(len(ems)))
    while active:
        for i in sorted(active):
            em = ems[i]
            for _ in range(min(chunk, cycles - done[i])):
                if em.status != "running":
                    break
                em.step()
                done[i] += 1
            if done[i] >= cycles or em.status != "running":
                active.discard(i)
    return done


def _with_stage_timers(em: Emulator) -> dict[str, int]:
    """Wrap every timed stage of `em`; returns the accumulator of ns per stage."""
    acc: dict[str, int] = defaultdict(int)
    em.ods.step = _timed(em.ods.step, acc, "ODS step")
    em.contact.compute = _timed(em.contact.compute, acc, "contact")
    em._record = _timed(em._record, acc, "telemetry (_record)")
    em._passivate = _timed(em._passivate, acc, "passivity (PO/PC, both arms)")
    for arm in em.arms:
        arm.mockup_state_W = _timed(arm.mockup_state_W, acc, "arm FK + twist")
        arm.sensor.measure = _timed(arm.sensor.measure, acc, "F/T chain (sensor+processing)")
        arm.processor.process = _timed(
            arm.processor.process, acc, "F/T chain (sensor+processing)"
        )
    for arm in em.arms:
        arm.vfdm.solve = _timed(arm.vfdm.solve, acc, f"VFDM arm {arm.index + 1}")
        arm.servo.step = _timed(arm.servo.step, acc, f"servo arm {arm.index + 1}")
    return acc


def stage_breakdown(scenario: str, cycles: int, repeats: int) -> list[tuple[dict, float]]:
    """[(µs per cycle of each stage, total µs per cycle)] of the reference (every switch
    off) and of the compiled loop (every switch on), over `cycles` hil cycles after
    prepare(), the two stepped in turn; of `repeats` such runs, each keeps its fastest."""
    best: list = [None, None]
    for _ in range(repeats):
        ems = [_prepared(scenario, set()), _prepared(scenario, set(SWITCHES))]
        accs = [_with_stage_timers(em) for em in ems]
        ran = _interleaved(ems, cycles)
        for k, (em, acc, n) in enumerate(zip(ems, accs, ran, strict=True)):
            total = float(np.sum(em.cycle_time_ns)) / n / 1e3
            out = {key: v / n / 1e3 for key, v in acc.items()}
            out["bookkeeping (rest)"] = total - sum(out.values())
            if best[k] is None or total < best[k][1]:
                best[k] = (out, total)
    return best


def cycle_costs(scenario: str, cycles: int, configs: dict[str, set[str]],
                repeats: int) -> dict[str, float]:
    """Mean µs per whole cycle (no stage timers) of each switch configuration, all
    stepped in turn; the fastest of `repeats` runs."""
    best: dict[str, float] = {}
    for _ in range(repeats):
        ems = [_prepared(scenario, on) for on in configs.values()]
        for label, em, n in zip(configs, ems, _interleaved(ems, cycles), strict=True):
            cost = float(np.sum(em.cycle_time_ns)) / n / 1e3
            best[label] = min(best.get(label, cost), cost)
    return best


def realtime_factor(scenario: str, duration_s: float | None,
                    compiled: bool) -> tuple[float, float, float]:
    """(realtime_factor incl. prepare, loop-only factor, simulated s) of a headless hil run.

    compiled=True is run_scenario itself (its metrics); compiled=False times the same
    thing, Emulator.run from prepare() to the end, with every switch off.
    """
    cfg = load_scenario(scenario)
    if compiled:
        res = run_scenario(cfg, mode="hil", duration_s=duration_s)
        em, rtf = res.emulator, float(res.metrics["realtime_factor"])
    else:
        em = Emulator(cfg, mode="hil")
        em.set_compiled(False)
        t0 = time.perf_counter()
        em.run(duration_s or cfg.loop.duration_s)
        rtf = em.t_s / (time.perf_counter() - t0)
    sim_s = em.cycles * em.dt_s
    loop_s = float(np.sum(em.cycle_time_ns)) / 1e9
    return rtf, sim_s / loop_s, sim_s


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
                    help="the Python VFDM path also in the compiled runs (numba kernel off)")
    args = ap.parse_args(argv)
    if args.no_kernel:
        vfdm_module._solve_compiled = None
    print(f"VFDM path in the compiled runs: "
          f"{'kernel' if vfdm_module.vfdm_kernel_available() else 'Python'}\n")
    cycles = args.cycles or (300 if args.quick else 3000)
    duration = 1.0 if args.quick else None
    vfdm_cycles = 100 if args.quick else 2000
    repeats = 1 if args.quick else 2

    print(f"## Cycle breakdown: collision, hil, {cycles} cycles after prepare()\n")
    print("Every switch off (Python reference) vs every switch on, the same cycles, the two "
          f"emulators stepped in turn (best of {repeats}).\n")
    (ref, ref_total), (fast, total) = stage_breakdown("collision", cycles, repeats)
    print("| stage | reference µs / cycle | compiled µs / cycle | speed-up | compiled share |")
    print("|---|---:|---:|---:|---:|")
    for k, v in fast.items():
        print(f"| {k} | {ref[k]:.1f} | {v:.1f} | {ref[k] / v:.1f}x | {100 * v / total:.0f}% |")
    print(f"| **total cycle** | **{ref_total:.1f}** | **{total:.1f}** | "
          f"**{ref_total / total:.1f}x** | 100% |")
    print(f"\nloop-only real-time factor from this: reference {CYCLE_US / ref_total:.1f}x, "
          f"compiled {CYCLE_US / total:.1f}x (cycle = {CYCLE_US:.0f} µs)\n")

    n_sw = max(100, cycles // 3)
    print(f"## Whole cycle by switch: collision, hil, {n_sw} cycles after prepare()\n")
    print("No stage timers; each row turns one optimisation off (or on) against the others; "
          f"all rows stepped in turn (best of {repeats}).\n")
    configs = {"every switch off (Python reference)": set(),
               "only the VFDM kernel on (the loop before issue 6)": {VFDM_SWITCH}}
    configs |= {f"all on but {name}": set(SWITCHES) - {name} for name in SWITCHES}
    configs["every switch on (default)"] = set(SWITCHES)
    costs = cycle_costs("collision", n_sw, configs, repeats)
    best = costs["every switch on (default)"]
    print("| configuration | µs / cycle | vs all on | loop-only real-time factor |")
    print("|---|---:|---:|---:|")
    for label, c in costs.items():
        print(f"| {label} | {c:.1f} | {c / best:.2f}x | {CYCLE_US / c:.1f} |")

    rtf_repeats = 1 if args.quick else 3
    print("\n## Real-time factor, headless hil\n")
    print(f"Compiled: run_scenario's metrics, best of {rtf_repeats}; reference: "
          "Emulator.run timed the same way, one run.\n")
    print("| scenario | simulated s | path | realtime_factor (incl. prepare) | loop only |")
    print("|---|---:|---|---:|---:|")
    rtf = {}
    for name in ("collision", "free-floating"):
        for compiled in (True, False):
            runs = [realtime_factor(name, duration, compiled)
                    for _ in range(rtf_repeats if compiled else 1)]
            r_metrics, r_loop, sim_s = max(runs)
            if compiled:
                rtf[name] = r_metrics
            path = "compiled (run_scenario)" if compiled else "reference"
            print(f"| {name} | {sim_s:.1f} | {path} | {r_metrics:.2f} | {r_loop:.2f} |")

    print("\n## VFDM cost per arm per cycle (same run: Python reference vs compiled kernel)\n")
    have_kernel = vfdm_module.vfdm_kernel_available()
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
    best_v = kernel.get(10, cost[10])
    ok_v = best_v <= VFDM_TARGET_US
    print(f"- VFDM <= {VFDM_TARGET_US:.0f} µs/arm/cycle at 10 iterations "
          f"({'kernel' if kernel else 'Python'}): {best_v:.1f} µs -> "
          f"{'MET' if ok_v else 'NOT MET'} (Python reference path: {cost[10]:.1f} µs)")
    ok_r = rtf["collision"] >= RTF_TARGET
    print(f"- collision hil realtime_factor >= {RTF_TARGET:.0f}: "
          f"{rtf['collision']:.2f} -> {'MET' if ok_r else 'NOT MET'} "
          f"(cycle {best:.1f} µs, {total:.1f} µs with the stage timers)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
