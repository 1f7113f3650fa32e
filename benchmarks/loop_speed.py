"""Loop speed benchmark: per-stage cycle cost, real-time factor, VFDM cost per solve.

    .venv/bin/python -m benchmarks.loop_speed                      # full
    .venv/bin/python -m benchmarks.loop_speed --quick              # small sizes (smoke test)
    .venv/bin/python -m benchmarks.loop_speed --against /tmp/old   # RTF of this tree vs another
    .venv/bin/python -m benchmarks.loop_speed --against /tmp/old --steps-only  # cycle only

Stages are timed by wrapping the very objects ``Emulator.step`` calls (instance attributes
shadow the methods, so the loop runs unchanged but for its tail, which the breakdown runs
as its stages: ``fuse_tail`` off); "rest (glue)" is everything else in the cycle. The
real-time factor is the one ``run_scenario`` writes into metrics.json (simulated time over
the wall time of the run, start-up included).

``--against TREE`` compares this tree with another checkout of the project (e.g.
``git worktree add /tmp/old <commit>``) in two ways: (1) the real-time factor, in a fresh
process for each tree in turn, ``--rounds`` times; (2) the cost of ``Emulator.step`` of both
trees in ONE process, stepped in turn in chunks of 100 cycles, so that both see the same
machine (the other tree's ``app`` package is copied under another name for that). On a
shared machine (2) is the steadier figure. It needs ``run_scenario``, ``load_scenario`` and
``Emulator`` (``prepare``, ``step``) in the other tree.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

VFDM_TARGET_US = 100.0
RTF_TARGET = 10.0
CYCLE_US = 2000.0
HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]


# --- real-time factor (works against any tree that has run_scenario) ------------------------


def realtime_factors(scenario: str, duration_s: float | None, repeats: int) -> list[dict]:
    """run_scenario's realtime_factor and cycle p50/p99 of `repeats` headless hil runs."""
    from app.runs.headless import run_scenario
    from app.scenarios import load_scenario

    out = []
    for _ in range(repeats):
        m = run_scenario(load_scenario(scenario), mode="hil", duration_s=duration_s).metrics
        out.append({"rtf": m["realtime_factor"], "p50": m["cycle_time_us"]["p50"],
                    "p99": m["cycle_time_us"]["p99"], "status": m["status"],
                    "simulated_s": m["duration_s"]})
    return out


def _rtf_in_process(tree: Path, scenarios: list[str], duration_s: float | None) -> dict:
    """realtime_factors of each scenario, one run each, in a fresh Python for `tree`."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    args = [sys.executable, str(HERE), "--rtf-json", *scenarios]
    if duration_s:
        args += ["--duration", str(duration_s)]
    proc = subprocess.run(args, env=env, cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compare_trees(other: Path, scenarios: list[str], rounds: int, duration_s: float | None):
    """Alternate fresh processes of this tree and `other`; print each round and the best."""
    trees = {"this tree": ROOT, f"{other}": other}
    runs: dict[str, dict[str, list[dict]]] = {t: defaultdict(list) for t in trees}
    print(f"\n## Real-time factor, this tree vs {other} ({rounds} rounds, alternating)\n")
    print("| round | tree | " + " | ".join(f"{s} RTF (p50 µs)" for s in scenarios) + " |")
    print("|---:|---|" + "---:|" * len(scenarios))
    for r in range(rounds):
        for name, tree in trees.items():
            res = _rtf_in_process(tree, scenarios, duration_s)
            cells = []
            for s in scenarios:
                runs[name][s].append(res[s])
                cells.append(f"{res[s]['rtf']:.2f} ({res[s]['p50']:.0f})")
            print(f"| {r + 1} | {name} | " + " | ".join(cells) + " |", flush=True)
    print("\n| scenario | best RTF, this tree | best RTF, other | ratio | median ratio "
          "| run's cycle p50 this / other (ratio) | run's cycle p99 this / other (ratio) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    this, that = runs["this tree"], runs[f"{other}"]
    for s in scenarios:
        a = [x["rtf"] for x in this[s]]
        b = [x["rtf"] for x in that[s]]
        cells = []
        for q in ("p50", "p99"):  # each run's own, over all its cycles; median of the rounds
            qa, qb = np.median([x[q] for x in this[s]]), np.median([x[q] for x in that[s]])
            cells.append(f"{qa:.1f} / {qb:.1f} ({qa / qb:.3f})")
        print(f"| {s} | {max(a):.2f} | {max(b):.2f} | {max(a) / max(b):.3f} "
              f"| {np.median(a) / np.median(b):.3f} | " + " | ".join(cells) + " |")


def _import_other_app(tree: Path, tmp: Path):
    """The other tree's ``app`` package, copied to tmp as ``other_app`` with its imports
    renamed, so that both trees' emulators can live in one process."""
    dest = tmp / "other_app"
    shutil.copytree(tree / "app", dest, ignore=shutil.ignore_patterns("__pycache__"))
    for py in dest.rglob("*.py"):
        text = py.read_text()
        text = re.sub(r"\b(from|import) app(\.|\b)", r"\1 other_app\2", text)
        py.write_text(text)
    sys.path.insert(0, str(tmp))
    import importlib

    return (importlib.import_module("other_app.sim.loop").Emulator,
            importlib.import_module("other_app.scenarios").load_scenario)


def compare_steps(other: Path, scenarios: list[str], chunks: int,
                  modes: tuple[str, ...] = ("hil",), chunk_cycles: int = 100) -> None:
    """µs per Emulator.step of both trees in one process, stepped in turn (each chunk's
    mean, and the p50 / p99 of the single cycles' compute times the emulators record)."""
    from app.scenarios import load_scenario
    from app.sim.loop import Emulator

    with tempfile.TemporaryDirectory() as tmp:
        OtherEmulator, other_load = _import_other_app(other, Path(tmp))  # noqa: N806
        print(f"\n## Emulator.step, this tree vs {other}, one process, {chunks} chunks of "
              f"{chunk_cycles} cycles each in turn\n")
        print("| scenario | mode | this tree µs (min / median) | other µs (min / median) "
              "| ratio of minima | median of chunk ratios | cycle p50 this / other (ratio) "
              "| cycle p99 this / other (ratio) |")
        print("|---|---|---:|---:|---:|---:|---:|---:|")
        cold_rows = []
        def fresh(scenario, mode):  # both emulators, prepared and past their first cycles
            ems = [Emulator(load_scenario(scenario), mode=mode),
                   OtherEmulator(other_load(scenario), mode=mode)]
            for em in ems:
                em.prepare()
                for _ in range(300):
                    em.step()
            return ems

        for scenario in scenarios:
            for mode in modes:
                ems = fresh(scenario, mode)
                us, cycle_us = [[], []], [[], []]
                for _ in range(chunks):
                    if any(em.status != "running" for em in ems):  # a run ended: both anew
                        ems = fresh(scenario, mode)
                    for k, em in enumerate(ems):
                        n0 = em.cycles
                        t0 = time.perf_counter_ns()
                        for _ in range(chunk_cycles):
                            em.step()
                        us[k].append((time.perf_counter_ns() - t0) / chunk_cycles / 1e3)
                        # each cycle's own compute time, as the emulator records it
                        cycle_us[k].append(em.cycle_time_ns[n0:em.cycles] / 1e3)
                a, b = np.array(us[0]), np.array(us[1])
                ca, cb = np.concatenate(cycle_us[0]), np.concatenate(cycle_us[1])
                pa, pb = np.percentile(ca, [50, 99]), np.percentile(cb, [50, 99])
                print(f"| {scenario} | {mode} | {a.min():.1f} / {np.median(a):.1f} "
                      f"| {b.min():.1f} / {np.median(b):.1f} | {a.min() / b.min():.3f} "
                      f"| {np.median(a / b):.3f} | {pa[0]:.1f} / {pb[0]:.1f} "
                      f"({pa[0] / pb[0]:.3f}) | {pa[1]:.1f} / {pb[1]:.1f} "
                      f"({pa[1] / pb[1]:.3f}) |", flush=True)
                cold_rows.append(_cold_row(scenario, mode, cycle_us))
        _print_cold(cold_rows, chunk_cycles)


def _cold_row(scenario: str, mode: str, cycle_us: list[list[np.ndarray]]) -> str:
    """One row of :func:`_print_cold`: per tree, the median of each chunk's first cycle
    (the one after the other tree's chunk) and the p99 of the cycles without it."""
    firsts = [np.median([c[0] for c in tree if len(c)]) for tree in cycle_us]
    warm = [np.percentile(np.concatenate([c[1:] for c in tree]), 99) for tree in cycle_us]
    return (f"| {scenario} | {mode} | {firsts[0]:.1f} / {firsts[1]:.1f} "
            f"({firsts[0] / firsts[1]:.3f}) | {warm[0]:.1f} / {warm[1]:.1f} "
            f"({warm[0] / warm[1]:.3f}) |")


def _print_cold(rows: list[str], chunk_cycles: int) -> None:
    """The p99 above, taken apart: each chunk's first cycle runs after the other tree's
    code has taken the CPU's caches; with 100 cycles per chunk (1 % of the samples, and
    the next few cycles are not warm either) those set the p99, with 1,000
    (``--chunk-cycles``) the warm loop's tail does. The p99 of the other cycles."""
    print("\n### The cold cycle: each chunk's first, after the other tree's chunk\n")
    print("| scenario | mode | first cycle of a chunk, median µs this / other (ratio) "
          "| cycle p99 without it, this / other (ratio) |")
    print("|---|---|---:|---:|")
    for row in rows:
        print(row)


# --- per-stage breakdown --------------------------------------------------------------------


def _timed(fn, acc: dict, key: str):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += time.perf_counter_ns() - t0

    return wrapper


def _with_stage_timers(em) -> dict[str, int]:
    """Wrap every timed stage of `em`; returns the accumulator of ns per stage."""
    acc: dict[str, int] = defaultdict(int)
    em.fuse_tail = False  # the stages one by one (app/sim/cycle_tail.py fuses the tail,
    # and in a one-arm run without passivity or gate the F/T chain with it)
    em.bodies_W = _timed(em.bodies_W, acc, "actual mockups (arm FK + twist)")
    interaction = em.interaction  # the contact's part of it (free flight: its early-out)
    interaction._contact_W = _timed(interaction._contact_W, acc, "contact (coal)")
    em.hand.wrenches_W = _timed(em.hand.wrenches_W, acc, "operator's hand")
    em.coupling.ods_input = _timed(em.coupling.ods_input, acc, "ODS coupling (passivity)")
    em._record = _timed(em._record, acc, "telemetry row")
    em.ods_advance = _timed(em.ods_advance, acc, "ODS step")
    em._tracking = _timed(em._tracking, acc, "tracking watchdog")
    for arm in em.arms:  # each arm's sensor path and command path (each one compiled call)
        arm.sense_rows = _timed(arm.sense_rows, acc, "F/T sensor + processing")
        arm.command_towards = _timed(arm.command_towards, acc,
                                     f"arm {arm.index + 1}: target, VFDM, servo, FK")
    return acc


def stage_breakdown(scenario: str, cycles: int, repeats: int) -> tuple[dict, float, int]:
    """(µs per cycle of each stage, total µs per cycle, cycles run) over `cycles` hil
    cycles after prepare(); of `repeats` runs, the one with the fastest total."""
    from app.scenarios import load_scenario
    from app.sim.loop import Emulator

    best = None
    for _ in range(repeats):
        em = Emulator(load_scenario(scenario), mode="hil")
        em.prepare()
        acc = _with_stage_timers(em)
        n = 0
        while n < cycles and em.status == "running":
            em.step()
            n += 1
        total = float(np.sum(em.cycle_time_ns)) / n / 1e3
        if best is None or total < best[1]:
            best = ({k: v / n / 1e3 for k, v in acc.items()}, total, n)
    return best


def print_breakdown(scenario: str, cycles: int, repeats: int) -> float:
    stages, total, n = stage_breakdown(scenario, cycles, repeats)
    print(f"\n## Cycle breakdown: {scenario}, hil, {n} cycles after prepare() "
          f"(best of {repeats})\n")
    print("| stage | µs / cycle | share |")
    print("|---|---:|---:|")
    for k, v in stages.items():
        print(f"| {k} | {v:.1f} | {100 * v / total:.0f}% |")
    rest = total - sum(stages.values())
    print(f"| rest (glue) | {rest:.1f} | {100 * rest / total:.0f}% |")
    print(f"| **total cycle** | **{total:.1f}** | 100% |")
    print("\n(the cycle's tail, ODS step to the arms' commands, as its stages: in a run "
          "they are one compiled call, app/sim/cycle_tail.py, and in a one-arm run without "
          "passivity or contact gate the F/T chain is in that call too)")
    print(f"\nloop-only real-time factor from this: {CYCLE_US / total:.1f}x "
          f"(cycle = {CYCLE_US:.0f} µs; stage timers included)")
    return total


# --- VFDM -----------------------------------------------------------------------------------


def vfdm_cost(iterations: int, cycles: int) -> float:
    """µs per Vfdm.solve at `iterations`, tracking a moving target from the collision arm."""
    from app.config import VfdmConfig
    from app.scenarios import load_scenario
    from app.sim.rotations import make_transform, rotvec_to_matrix
    from app.sim.ur10e import T_F_C_from_config
    from app.sim.vfdm import Vfdm

    robot = load_scenario("collision").robots[0]
    T_F_C = T_F_C_from_config(robot)
    cfg = VfdmConfig(iterations=iterations)
    v = Vfdm(cfg, T_F_C, np.array(robot.q_home_rad))
    T0 = v.tcp_pose()
    v.solve(T0)
    targets = [make_transform(rotvec_to_matrix([0.0, 0.0, 0.2 * k / cycles]) @ T0[:3, :3],
                              T0[:3, 3] + np.array([0.05, 0.02, 0.0]) * k / cycles)
               for k in range(cycles)]
    best = float("inf")
    for _ in range(3):
        v.reset(np.array(robot.q_home_rad))
        t0 = time.perf_counter_ns()
        for T in targets:
            v.solve(T)
        best = min(best, (time.perf_counter_ns() - t0) / cycles / 1e3)
    return best


def _positive(text: str) -> int:
    """An argument that must be a whole number of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument("--cycles", type=int, default=None, help="cycles for the breakdown")
    ap.add_argument("--against", type=Path, default=None,
                    help="another checkout: compare real-time factors, this tree vs that")
    ap.add_argument("--rounds", type=int, default=5, help="rounds of --against")
    ap.add_argument("--chunks", type=_positive, default=200,
                    help="chunks per tree in --against's one-process comparison")
    ap.add_argument("--chunk-cycles", type=_positive, default=100,
                    help="cycles per chunk in --against's one-process comparison")
    ap.add_argument("--steps-only", action="store_true",
                    help="--against: the one-process Emulator.step comparison only")
    ap.add_argument("--scenarios", nargs="+", default=None,
                    help="--against: these scenarios (default collision, "
                         "free-floating-scripted)")
    ap.add_argument("--duration", type=float, default=None, help="simulated s of RTF runs")
    ap.add_argument("--rtf-json", nargs="+", metavar="SCENARIO", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.rtf_json:  # one round for compare_trees, in a fresh process
        res = {s: realtime_factors(s, args.duration, 1)[0] for s in args.rtf_json}
        print(json.dumps(res))
        return 0
    if args.against is not None:
        other = args.against.resolve()
        scenarios = ["collision"]  # the scripted free-floating run, where both trees have it
        if args.scenarios:
            scenarios = args.scenarios
        elif (other / "app" / "scenarios" / "free-floating-scripted.toml").is_file():
            scenarios.append("free-floating-scripted")
        else:
            print("(the other tree has no free-floating-scripted; its free-floating is the "
                  "scripted one, this tree's is hand-driven: compared on collision only)")
        compare_steps(other, scenarios, args.chunks, ("hil", "ideal"), args.chunk_cycles)
        if not args.steps_only:
            compare_trees(other, scenarios, args.rounds, args.duration)
        return 0

    cycles = args.cycles or (300 if args.quick else 3000)
    repeats = 1 if args.quick else 3
    duration = 1.0 if args.quick else None
    total = print_breakdown("collision", cycles, repeats)
    print_breakdown("free-floating-scripted", cycles, repeats)

    print(f"\n## Real-time factor, headless hil (run_scenario's metric, best of {repeats})\n")
    print("| scenario | simulated s | realtime_factor | cycle p50 / p99 µs | status |")
    print("|---|---:|---:|---:|---|")
    rtf = {}
    for scenario in ("collision", "free-floating-scripted"):
        runs = realtime_factors(scenario, duration, repeats)
        r = max(runs, key=lambda x: x["rtf"])
        rtf[scenario] = r["rtf"]
        print(f"| {scenario} | {r['simulated_s']:.1f} | {r['rtf']:.2f} | "
              f"{r['p50']:.0f} / {r['p99']:.0f} | {r['status']} |")

    print("\n## VFDM cost per arm per cycle\n")
    print("| iterations | µs / solve |")
    print("|---:|---:|")
    costs = {}
    for it in (1, 10, 50):
        costs[it] = vfdm_cost(it, 200 if args.quick else 2000)
        print(f"| {it} | {costs[it]:.1f} |")

    met = "MET" if costs[10] <= VFDM_TARGET_US else "NOT MET"
    print("\n## Targets\n")
    print(f"- VFDM <= {VFDM_TARGET_US:.0f} µs/arm/cycle at 10 iterations: {costs[10]:.1f} µs "
          f"-> {met}")
    met = "MET" if rtf["collision"] >= RTF_TARGET else "NOT MET"
    if args.quick:
        met = "not judged (--quick: a 1 s run is mostly start-up)"
    print(f"- collision hil realtime_factor >= {RTF_TARGET:.0f}: {rtf['collision']:.2f} -> "
          f"{met} (cycle {total:.1f} µs with the stage timers)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
