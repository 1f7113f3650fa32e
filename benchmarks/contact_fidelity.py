"""How faithful is an emulated contact? HIL runs against the converged ideal reference.

    .venv/bin/python -m benchmarks.contact_fidelity             # the table (seeds 0-4)
    .venv/bin/python -m benchmarks.contact_fidelity --map       # + the fidelity map (PNG)
    .venv/bin/python -m benchmarks.contact_fidelity --quick     # seed 0 only
    .venv/bin/python -m benchmarks.contact_fidelity --calibration 30   # bias calibration
    .venv/bin/python -m benchmarks.contact_fidelity --calibration-check  # the interval
    .venv/bin/python -m benchmarks.contact_fidelity --seeds            # per-seed figures
    .venv/bin/python -m benchmarks.contact_fidelity --seeds --factors  # + bias factors
    .venv/bin/python -m benchmarks.contact_fidelity --rig-table --rig-seeds 10   # the lab's rig
    .venv/bin/python -m benchmarks.contact_fidelity --pool 200 --first-seed 7000  # vs forecast
    .venv/bin/python -m benchmarks.contact_fidelity --replicate-means 40 --first-seed 7000
    .venv/bin/python -m benchmarks.contact_fidelity --mismatch 10 --first-seed 7000  # model

Each figure is of a whole headless run (`orbit-emulator run`), measured against the ideal
run of the same configuration (contact integrated within the ODS step: app/sim/reference.py).
Chains compared, all on the same simulated hardware (F/T noise and bias, sensor and servo
delays, servo bandwidth and limits):

* ``paper``: the paper's chain (payload + inertial compensation, 30 Hz low-pass, 4 N
  deadband), nothing else;
* ``passivity``: + the passivity layer alone (the landed default before lag compensation,
  its tank of 1 mJ);
* ``compensated``: the collision scenario's chain: lag compensation + contact gate + pair
  fusion + passivity layer (README "Fidelity");
* ``comp. without the lead``: the compensated chain with ``[compensation] enabled = false``
  (contact gate, pair fusion and passivity layer kept): what the lead itself does;
* ``comp. + VFDM sync``: the compensated chain with the VFDM restarted from the measured
  joints every cycle ([vfdm] sync_to_measured);
* ``comp., noise/10`` and ``comp., no noise``: the compensated chain with a sensor ten times
  quieter, and without noise: what limits it.

"chatter": the runs whose first contact is two or more touches less than 50 ms apart
(metrics ``touches``; the ideal contact is one touch).

Free-floating: tracking, each push's Δv against impulse × force_scale / mass, and the
spin left after the force-only pushes.

``--seeds``: the shipped collision chain over many seeds (sponge vs rigid on seeds 0-29,
rigid vs rigid on 0-19; ``--first-seed 1000`` for the tuning seeds 1000-1029;
``--sponge-seeds N --rigid-seeds M`` for a shorter try), without noise (one run: without
noise every seed is the same run) and with the data sheet's, each run as the CLI runs it
(the pre-flight's forecast, the run's interval): mean restitution error, its standard
deviation, the worst run, the median off-normal share, how many intervals hold the ideal
restitution, the forecast's sd against the across-seed sd, stops; with ``--factors``
each bias factor's share (issue 28 item 7, in one run): the mean error with that
part of the chain as it was (``FACTORS``) minus the shipped chain's, same seeds. The
table is one function per column (``SEED_COLUMNS``), so that columns can be added. Then
the ideal run with the chain's noise acting on the pair during the contact
(``NoisyIdeal``, ten times the seeds): what the noise does to a perfect emulator.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import statistics
import time
from pathlib import Path

import numpy as np

from app.config import EmulatorConfig, assignment_override, merge_overrides
from app.runs.headless import (
    checked_reference,
    collision_of,
    headless_config,
    ideal_collision,
    run_scenario,
)
from app.runs.metrics import compare_with_ideal, sensing_limits
from app.runs.rendering import RENDERING_TOLERANCE
from app.runs.uncertainty import Z95, forecast
from app.scenarios import load_scenario
from app.sim.loop import Emulator

SEEDS = list(range(10))
"""Ten seeds: the sponge's single-run spread is ±40 %, so the mean of ten is known to about
±13 % (its standard error, printed beside it)."""
RIGID = ['satellites.1.material="rigid"', "loop.duration_s=7"]
"""7 s: an impact at the physics' e = 0.95 sends the satellites back out at 0.076 m/s, and
by 12 s they would be at the arms' bases (a workspace stop, not a fidelity figure)."""
PAPER = ["compensation.enabled=false", "wrench.contact_gate=false",
         "wrench.fuse_pair_contact=false", "passivity.enabled=false"]
PASSIVITY = PAPER[:-1] + ["passivity.enabled=true", "passivity.tank_max_J=0.001"]
NOISE_10 = ["sensor.noise_force_N=0.16667", "sensor.noise_torque_Nm=0.006667"]
NO_NOISE = ["sensor.noise_force_N=0", "sensor.noise_torque_Nm=0"]
CHAINS = {
    "paper": PAPER,
    "passivity": PASSIVITY,
    "compensated": [],
    "comp. without the lead": ["compensation.enabled=false"],
    "comp. + VFDM sync": ["vfdm.sync_to_measured=true"],
    "comp., noise/10": NOISE_10,
    "comp., no noise": NO_NOISE,
}


def configure(base: EmulatorConfig, assignments: list[str]) -> EmulatorConfig:
    for a in assignments:
        base = merge_overrides(base, assignment_override(a))
    return base


def collision_run(args: tuple) -> dict:
    """One hil run of the collision scenario with the assignments; its collision metrics."""
    assignments, seed, ideal = args
    config = configure(load_scenario("collision"), assignments + [f"loop.seed={seed}"])
    em = run_scenario(config, duration_s=config.loop.duration_s, with_ideal=False).emulator
    from app.runs.metrics import collision_metrics
    bodies = {arm.satellite + 1: f"rob{arm.index + 1}" for arm in em.arms}
    coll = collision_metrics(em.telemetry.rows(), em.telemetry.index, em.dt_s, bodies=bodies)
    if coll is not None:
        compare_with_ideal(coll, ideal, sensing_limits(em))
    return {"collision": coll, "status": em.status,
            "removed_J": None if em.coupling.dissipated_J() is None
            else em.coupling.dissipated_J()["force"]}


def _ideal(assignments: list[str]) -> dict:
    config = configure(load_scenario("collision"), assignments)
    return ideal_collision(config, config.loop.duration_s)


def _fmt(values: list[float | None], pct: bool = True) -> str:
    """mean (standard error of the mean) ± sd (worst): errors in % (worst: furthest from
    0), ratios (mean ± sd, worst furthest from 1); runs without a figure are counted."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "—"
    if len(vals) < len(values):
        missing = f", {len(values) - len(vals)} without"
    else:
        missing = ""
    sd = statistics.stdev(vals) if len(vals) > 1 else 0.0
    se = sd / math.sqrt(len(vals))
    if pct:
        worst = max(vals, key=abs)
        return (f"{100 * statistics.fmean(vals):+.1f} % (SE {100 * se:.1f}) ± {100 * sd:.1f} "
                f"(worst {100 * worst:+.1f}{missing})")
    worst = max(vals, key=lambda v: abs(v - 1.0))
    return f"{statistics.fmean(vals):.3f} ± {sd:.3f} (worst {worst:.3f}{missing})"


def collision_table(pool, seeds: list[int]) -> list[str]:
    lines = ["| case | chain | restitution error: mean % (SE of the mean) ± sd (worst) "
             "| true impulse ratio "
             "| impulse balance (worst) | safety stops | chatter | passivity removed (mean) |",
             "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for case, extra in (("sponge vs rigid", []), ("rigid vs rigid", RIGID)):
        ideal = _ideal(extra)
        for chain, assignments in CHAINS.items():
            runs = pool.map(collision_run, [(extra + assignments, s, ideal) for s in seeds])
            colls = [r["collision"] for r in runs]
            err = [c["restitution_error"] if c else None for c in colls]
            ratio = [c["true_impulse_ratio"]["sat1"] if c and c["true_impulse_ratio"] else None
                     for c in colls]
            bal = [c["impulse_balance"] for c in colls if c and c["impulse_balance"] is not None]
            stops = sum(r["status"] == "safety_stop" for r in runs)
            chatter = sum(c["touches"] > 1 for c in colls if c)
            removed = [r["removed_J"] for r in runs if r["removed_J"] is not None]
            lines.append(
                f"| {case} (e_ideal {ideal['restitution']:.3f}) | {chain} | {_fmt(err)} | "
                f"{_fmt(ratio, pct=False)} | {max(bal) if bal else float('nan'):.3f} | "
                f"{stops}/{len(runs)} | {chatter}/{len(runs)} | "
                + (f"{(1e3 * statistics.fmean(removed)):.2f} mJ |" if removed else "— |"))
            print(lines[-1], flush=True)
    return lines


SEED_CASES = {"sponge vs rigid": ([], 30), "rigid vs rigid": (RIGID, 20)}
"""Each case's assignments and how many seeds it runs."""
NOISES = {"no noise": NO_NOISE, "default noise": []}
FACTORS = {
    "measured contact force": ['wrench.contact_force="measured"'],
    "no-pull clamp": ["wrench.contact_no_pull=true"],
    "30 Hz filter in contact": ["wrench.contact_lowpass_hz=30"],
    "tank 1 mJ": ["passivity.tank_max_J=0.001"],
    "no estimator": ["wrench.contact_estimator=false"],
    "no pair fusion": ["wrench.fuse_pair_contact=false"],
    "no contact gate (deadband always)": ["wrench.contact_gate=false",
                                          "wrench.fuse_pair_contact=false",
                                          "wrench.contact_estimator=false"],
    "deadband without its noise floor": ["wrench.deadband_noise_sigmas=0"],
    "no lag compensation": ["compensation.enabled=false"],
    "no passivity layer": ["passivity.enabled=false"],
}
"""The parts of the chain that turned (or may turn) the noise or the loop's lag into a
bias, each switched off or back to what it was before issue 28: what each contributes
(its mean error minus the shipped one). The contact gate's row also drops the fusion and
the estimator, which need it: the deadband then applies to the contact too."""


def seed_run(args: tuple) -> dict:
    """One run's figures for the per-seed table: the collision metrics and the status."""
    run = collision_run(args)
    coll = run["collision"]
    off = (max(v for v in coll["off_normal_ratio"].values() if v is not None)
           if coll and any(v is not None for v in coll["off_normal_ratio"].values()) else None)
    return {"error": coll["restitution_error"] if coll else None, "off_normal": off,
            "status": run["status"]}


def fidelity_run(args: tuple) -> dict:
    """One run for the per-seed table, as the CLI runs it given its reference (with its
    forecast): its error, off-normal share and status, and its interval and whether it
    holds the ideal restitution; ``forecast_sd``: the reference's."""
    assignments, seed, reference = args
    run = interval_run((assignments, seed, reference))
    coll = run.pop("collision")
    off = None
    if coll and any(v is not None for v in coll["off_normal_ratio"].values()):
        off = max(v for v in coll["off_normal_ratio"].values() if v is not None)
    ei = reference["restitution"]
    fc = reference.get("forecast") or {}
    return {**run, "off_normal": off,
            "holds": None if run["interval"] is None
            else run["interval"][0] <= ei <= run["interval"][1],
            "forecast_sd": fc.get("restitution_sd")}


def _errors(runs: list[dict]) -> list[float]:
    return [r["error"] for r in runs if r["error"] is not None]


def col_mean(runs: list[dict]) -> str:
    e = _errors(runs)
    if not e:
        return "—"
    se = statistics.stdev(e) / math.sqrt(len(e)) if len(e) > 1 else 0.0
    return f"{100 * statistics.fmean(e):+.1f} % (SE {100 * se:.1f})"


def col_sd(runs: list[dict]) -> str:
    e = _errors(runs)
    return f"{100 * statistics.stdev(e):.1f} %" if len(e) > 1 else "—"


def col_worst(runs: list[dict]) -> str:
    e = _errors(runs)
    return f"{100 * max(e, key=abs):+.1f} %" if e else "—"


def col_off_normal(runs: list[dict]) -> str:
    v = [r["off_normal"] for r in runs if r["off_normal"] is not None]
    return f"{100 * statistics.median(v):.2f} %" if v else "—"


def col_finished(runs: list[dict]) -> str:
    return f"{sum(r['status'] == 'finished' for r in runs)}/{len(runs)}"


def col_coverage(runs: list[dict]) -> str:
    held = [r.get("holds") for r in runs if r.get("holds") is not None]
    return f"{sum(held)}/{len(held)}" if held else "—"


def col_forecast(runs: list[dict]) -> str:
    """The forecast's sd of e against the across-seed sd of e."""
    e = [r["restitution"] for r in runs if r.get("restitution") is not None]
    fc = next((r["forecast_sd"] for r in runs if r.get("forecast_sd") is not None), None)
    if fc is None or len(e) < 2:
        return "—" if fc is None else f"{fc:.3f} / —"
    sd = statistics.stdev(e)
    return f"{fc:.3f} / {sd:.3f}" + (f" = {fc / sd:.2f}" if sd > 0 else "")


SEED_COLUMNS = {
    "mean error (SE)": col_mean,
    "sd": col_sd,
    "worst": col_worst,
    "off-normal share (median)": col_off_normal,
    "interval holds e_ideal": col_coverage,
    "forecast sd / sd of e across seeds": col_forecast,
    "finished": col_finished,
}
"""The per-seed table's columns: name → function of the case's runs."""


def _seed_runs(pool, extra: list[str], seeds: list[int], ideal: dict) -> list[dict]:
    return pool.map(seed_run, [(extra, s, ideal) for s in seeds])


class NoisyIdeal(Emulator):
    """The ideal run (contact integrated within the step) with the force noise the hil
    chain hands the ODS during a contact acting on the pair: per cycle, while the bodies
    touch and 3 cycles after (the gate's hold), ±n with n ~ N(0, σ²/2 per axis) on the two
    satellites (the fused estimate of two sensors of σ each, the low-pass bypassed). What
    a perfect emulator with this sensor would give: the noise's own effect on the
    contact, which no processing of the force removes."""

    def __init__(self, config: EmulatorConfig, seed: int) -> None:
        super().__init__(config, mode="ideal")
        self.rng = np.random.default_rng(seed)
        self.sigma_N = config.sensor.noise_force_N / math.sqrt(2.0)
        self._hold = 0

    def ods_advance(self, force_R, torque_B, own=None):
        if self.interaction.contact_active or self._overlap(self.ods.y):
            self._hold = 3
        if self._hold > 0:
            self._hold -= 1
            n = self.sigma_N * self.rng.standard_normal(3)
            noise = np.zeros_like(force_R)
            noise[0], noise[1] = -n, n
            own = (noise, np.zeros_like(torque_B)) if own is None else (own[0] + noise,
                                                                          own[1])
        return super().ods_advance(force_R, torque_B, own)


def noisy_ideal_error(args: tuple) -> float | None:
    """One NoisyIdeal run's restitution error against the noise-free ideal."""
    assignments, seed, ideal = args
    config = configure(load_scenario("collision"), assignments)
    em = NoisyIdeal(config, seed)
    em.run(config.loop.duration_s)
    e = collision_of(em).get("restitution")
    return None if e is None else (e - ideal["restitution"]) / ideal["restitution"]


def noisy_ideal_table(pool, first_seed: int, repeat: int = 10) -> None:
    """Per case, NoisyIdeal over ``repeat`` times the case's seeds: the bias and spread the
    sensor's noise gives a perfect emulator."""
    print("\n| case | perfect emulator + the chain's noise: mean error (SE) | sd | runs |")
    print("|---|---|---|---|")
    for case, (extra, n) in SEED_CASES.items():
        ideal = _ideal(extra)
        seeds = range(first_seed, first_seed + repeat * n)
        e = [x for x in pool.map(noisy_ideal_error, [(extra, s, ideal) for s in seeds])
             if x is not None]
        sd = statistics.stdev(e)
        print(f"| {case} | {100 * statistics.fmean(e):+.1f} % (SE "
              f"{100 * sd / math.sqrt(len(e)):.1f}) | {100 * sd:.1f} % | "
              f"{len(e)}/{len(seeds)} |", flush=True)


def seeds_table(pool, first_seed: int, factors: bool | list[str],
                counts: dict[str, int] | None = None) -> None:
    """The shipped chain over SEED_CASES' seeds from ``first_seed`` (``counts``: per case,
    another number of seeds), without noise and with the data sheet's, each run as the
    CLI runs it (its pre-flight's forecast, its interval), and (``factors``) each bias
    factor's share (those runs without their interval)."""
    cases = {case: (extra, (counts or {}).get(case, n)) for case, (extra, n) in
             SEED_CASES.items()}
    names = list(SEED_COLUMNS)
    print("| case | noise | runs | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 3) + "|")
    shipped = {}
    for case, (extra, n) in cases.items():
        ideal = _ideal(extra)
        for noise, assignments in NOISES.items():
            seeds = [first_seed] if noise == "no noise" else list(range(first_seed, first_seed + n))
            config = configure(load_scenario("collision"), extra + assignments)
            config = headless_config(config, config.loop.duration_s)
            reference = checked_reference(config, config.loop.duration_s)
            runs = pool.map(fidelity_run, [(extra + assignments, s, reference) for s in seeds])
            shipped[(case, noise)] = runs
            print(f"| {case} (e_ideal {ideal['restitution']:.3f}) | {noise} | "
                  f"{'1 (every seed alike)' if len(seeds) == 1 else len(seeds)} | "
                  + " | ".join(f(runs) for f in SEED_COLUMNS.values()) + " |", flush=True)
    if not factors:
        return
    print("\n| case | noise | factor switched off or as it was | mean error with it | "
          "its share |")
    print("|---|---|---|---|---|")
    for case, (extra, n) in cases.items():
        ideal = _ideal(extra)
        for noise, assignments in NOISES.items():
            seeds = [first_seed] if noise == "no noise" else list(range(first_seed, first_seed + n))
            base = statistics.fmean(_errors(shipped[(case, noise)]))
            for factor, change in FACTORS.items():
                if isinstance(factors, list) and factor not in factors:
                    continue
                runs = _seed_runs(pool, extra + assignments + change
                                  + ["uncertainty.enabled=false"], seeds, ideal)
                e = _errors(runs)
                share = (f"{100 * (statistics.fmean(e) - base):+.1f} points"
                         if e else "—")
                print(f"| {case} | {noise} | {factor} | {col_mean(runs)} | {share} |",
                      flush=True)


def calibration_table(pool, seeds: list[int]) -> None:
    """The compensated sponge with the start-up bias calibration averaged over 0.5 s and
    2 s: what the bias left after it does to the restitution."""
    ideal = _ideal([])
    print(f"| calibration | restitution error over {len(seeds)} seeds: mean % (SE) ± sd "
          f"(worst) | true impulse ratio | chatter |")
    print("|---|---|---|---|")
    for seconds in (0.5, 2.0):
        runs = pool.map(collision_run, [([f"wrench.calibration_s={seconds}"], s, ideal)
                                        for s in seeds])
        colls = [r["collision"] for r in runs]
        err = [c["restitution_error"] if c else None for c in colls]
        ratio = [c["true_impulse_ratio"]["sat1"] if c and c["true_impulse_ratio"] else None
                 for c in colls]
        chatter = sum(c["touches"] > 1 for c in colls if c)
        print(f"| {seconds:g} s | {_fmt(err)} | {_fmt(ratio, pct=False)} | "
              f"{chatter}/{len(runs)} |", flush=True)


HERTZ_SCALE = 12.6
"""k of the n = 1.5 law over k of the linear one: 1 / sqrt(6.3 mm), the sponge contact's
peak depth, so that the Hertz contact peaks at about the same force and depth."""
MISMATCHES = {
    "as modelled (linear, as drawn, frictionless)": [],
    "Hertz law (n = 1.5)": ["materials.sponge.exponent=1.5", "materials.rigid.exponent=1.5",
                            f"materials.sponge.stiffness_Npm={500.0 * HERTZ_SCALE:g}",
                            f"materials.rigid.stiffness_Npm={2.0e4 * HERTZ_SCALE:g}"],
    "mockups 2 mm larger than drawn": ["satellites.0.size_error_m=0.002",
                                       "satellites.1.size_error_m=0.002"],
    "friction mu = 0.3": ["materials.sponge.friction=0.3", "materials.rigid.friction=0.3"],
}
"""Contacts the lab's model does not describe: the identification fits F = k d (1 + c ḋ),
the gate and the estimator use the drawn boxes; each case is also the ideal reference
(the physics as it is), so the error is the chain's against the real contact. The run's
interval and forecast replicate the configured contact, here the true one: a lab's
digital twin would have its model instead, so the table also gives the coverage of the
interval widened by the modelled contact's systematic error δ (the first case's)."""


def mismatch_table(pool, first_seed: int, n: int) -> None:
    """The shipped collision (sponge vs rigid, default sensor) with each MISMATCHES case:
    mean error, sd, worst, off-normal share, interval coverage, forecast / across-seed sd
    over seeds first_seed.. (each run as the CLI runs it)."""
    names = list(SEED_COLUMNS) + ["holds e_ideal with the modelled contact's δ",
                                  "without noise (δ)"]
    seeds = list(range(first_seed, first_seed + n))
    print(f"| contact (sponge vs rigid, seeds {seeds[0]}-{seeds[-1]}) | e_ideal | "
          + " | ".join(names) + " |")
    print("|---" * (len(names) + 2) + "|")
    modelled_delta = None
    for case, extra in MISMATCHES.items():
        config = configure(load_scenario("collision"), extra)
        config = headless_config(config, config.loop.duration_s)
        reference = checked_reference(config, config.loop.duration_s)
        delta = (reference.get("forecast") or {}).get("restitution_systematic") or 0.0
        if modelled_delta is None:
            modelled_delta = delta  # (the first case: the contact as the lab models it)
        runs = pool.map(fidelity_run, [(extra, s, reference) for s in seeds])
        ei = reference["restitution"]
        lab = [r["restitution"] - Z95 * r["sd"] - max(modelled_delta, 0.0) <= ei
               <= r["restitution"] + Z95 * r["sd"] + max(-modelled_delta, 0.0)
               for r in runs if r["restitution"] is not None and r["sd"] is not None]
        print(f"| {case} | {ei:.3f} | "
              + " | ".join(f(runs) for f in SEED_COLUMNS.values())
              + f" | {sum(lab)}/{len(lab)} | {100 * delta / ei:+.1f} % |", flush=True)


FEW_FORECAST = 60
"""The forecast's replicate count before issue 28's calibration follow-up (shown beside)."""
CHECK_CASES = {"sponge vs rigid": ([], list(range(30))), "rigid vs rigid": (RIGID, list(range(20)))}
"""The calibration check's cases: the shipped collision over seeds 0-29, rigid vs rigid
over seeds 0-19 (issue 28), default sensor."""


def interval_run(args: tuple) -> dict:
    """One hil run (headless, as the CLI runs it, given its reference): the collision's
    restitution, its sd and interval, and how the run ended."""
    assignments, seed, reference = args
    config = configure(load_scenario("collision"), assignments + [f"loop.seed={seed}"])
    t0 = time.perf_counter()
    result = run_scenario(config, ideal=reference, preflight_done=True)
    total_s = time.perf_counter() - t0
    coll = result.metrics["collision"] or {}
    run_wall_s = result.metrics["duration_s"] / result.metrics["realtime_factor"]
    return {"status": result.metrics["status"], "restitution": coll.get("restitution"),
            "error": coll.get("restitution_error"), "sd": coll.get("restitution_sd"),
            "interval": coll.get("restitution_interval_95"),
            "wall_s": total_s - run_wall_s, "run_wall_s": run_wall_s, "collision": coll}


def calibration_check(pool, cases: dict = CHECK_CASES, assignments: list[str] = ()) -> list[str]:
    """Per case: the restitution's mean error and sd over the seeds, how many runs' 95 %
    intervals hold the ideal restitution, their median half-width against 1.96 x the
    across-seed sd, and the pre-flight's forecast sd against the across-seed sd
    (docs/fidelity-uncertainty.md)."""
    lines = ["| case | seeds | mean error (SE) | sd of e across seeds | interval holds e_ideal "
             "| median half-width / (1.96 sd) | forecast sd (its SE) / sd "
             "| the same with 60 forecast replicates | runs without e "
             "| after the loop: replicates + metrics (median) / the loop's wall time "
             "| pre-flight with its forecast |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for case, (extra, seeds) in cases.items():
        config = configure(load_scenario("collision"), list(extra) + list(assignments))
        config = headless_config(config, config.loop.duration_s)
        t0 = time.perf_counter()
        reference = checked_reference(config, config.loop.duration_s)
        forecast_wall_s = time.perf_counter() - t0
        few = forecast(configure(config, [f"uncertainty.forecast_replicates={FEW_FORECAST}"]),
                       reference)
        runs = pool.map(interval_run, [(list(extra) + list(assignments), s, reference)
                                       for s in seeds])
        lines.append(_check_row(case, seeds, reference, runs, forecast_wall_s, few))
        print(lines[-1], flush=True)
    return lines


def _check_row(case: str, seeds: list[int], reference: dict, runs: list[dict],
               forecast_wall_s: float, few: dict | None = None) -> str:
    ei = reference["restitution"]
    got = [r for r in runs if r["restitution"] is not None]
    e = np.array([r["restitution"] for r in got])
    err = (e - ei) / ei
    sd = float(np.std(e, ddof=1))
    with_interval = [r for r in got if r["interval"] is not None]
    holds = sum(r["interval"][0] <= ei <= r["interval"][1] for r in with_interval)
    half = float(np.median([r["sd"] * 1.959964 for r in with_interval])) if with_interval \
        else float("nan")
    fc = (reference.get("forecast") or {}).get("restitution_sd")
    fc_se = (reference.get("forecast") or {}).get("restitution_sd_se")
    fc_few = (few or {}).get("restitution_sd")
    rep_wall = float(np.median([r["wall_s"] for r in got if r["wall_s"] is not None]))
    run_wall = float(np.median([r["run_wall_s"] for r in got]))
    def ratio(a: float, b: float) -> str:
        return f"{a:.3f} / {b:.3f}" + (f" = {a / b:.2f}" if b > 0 else "")

    return (f"| {case} (e_ideal {ei:.3f}) | {seeds[0]}-{seeds[-1]} | "
            f"{100 * err.mean():+.1f} % ({100 * err.std(ddof=1) / math.sqrt(len(err)):.1f}) | "
            f"{sd:.3f} ({100 * sd / ei:.0f} % of e_ideal) | {holds}/{len(runs)} | "
            f"{ratio(half, 1.959964 * sd)} | "
            + ("— | " if fc is None else
               f"{ratio(fc, sd)}".replace(" / ", f" ({fc_se or 0:.3f}) / ", 1) + " | ")
            + ("— | " if fc_few is None else f"{ratio(fc_few, sd)} | ")
            + f"{len(runs) - len(got)} | {rep_wall:.2f} s / {run_wall:.2f} s | "
            f"{forecast_wall_s:.1f} s |")


def pool_run(args: tuple) -> float | None:
    """One hil run as the CLI runs it, given its reference, without its interval
    (``[uncertainty] enabled = false``: the snapshot is a copy, the run is the same): its
    restitution."""
    assignments, seed, reference = args
    config = configure(load_scenario("collision"),
                       assignments + [f"loop.seed={seed}", "uncertainty.enabled=false"])
    result = run_scenario(config, ideal=reference, preflight_done=True)
    return (result.metrics["collision"] or {}).get("restitution")


POOL_FORECASTS = (60, 200, 600)
"""The forecast's replicate counts the pool compares (the first 60 or 200 of the 600 are
the same draws: the forecast's stream is the configuration's)."""


def _num(x: float | None) -> str:
    return "—" if x is None else f"{x:.4f}"


def spread_pool(pool, first_seed: int, n: int) -> list[str]:
    """Per case, ``n`` seeds from ``first_seed`` without intervals: the restitution's mean
    error and across-seed sd, each with its standard error (:func:`sd_standard_error`),
    the sd's skewness, and the forecast with 60, 200 and 600 replicates against it; the
    share of runs within 1.96 x the 600-replicate forecast sd of the ideal restitution
    (the coverage of an interval of that width)."""
    from app.runs.uncertainty import sd_standard_error

    lines = ["| case | seeds | mean error (SE) | sd of e across seeds (SE) | skewness | "
             + " | ".join(f"forecast, {k} replicates: sd (SE) / across-seed sd"
                          for k in POOL_FORECASTS)
             + f" | forecast mean error ({POOL_FORECASTS[-1]}) | within 1.96 x that forecast's "
             "sd of e_ideal |",
             "|---" * (7 + len(POOL_FORECASTS)) + "|"]
    print("\n".join(lines), flush=True)
    for case, (extra, _) in CHECK_CASES.items():
        base = configure(load_scenario("collision"), list(extra))
        config = headless_config(base, base.loop.duration_s)
        reference = ideal_collision(config, config.loop.duration_s)
        ei = reference["restitution"]
        fc = {k: forecast(configure(config, [f"uncertainty.forecast_replicates={k}"]),
                          reference) for k in POOL_FORECASTS}
        seeds = list(range(first_seed, first_seed + n))
        e = np.array([x for x in pool.map(pool_run, [(list(extra), s, reference)
                                                     for s in seeds]) if x is not None])
        sd, err = float(np.std(e, ddof=1)), (e - ei) / ei
        skew = float(np.mean((e - e.mean()) ** 3) / np.mean((e - e.mean()) ** 2) ** 1.5)
        big = fc[POOL_FORECASTS[-1]]
        lines.append(
            f"| {case} (e_ideal {ei:.3f}) | {seeds[0]}-{seeds[-1]} ({len(e)} with e) | "
            f"{100 * err.mean():+.1f} % ({100 * err.std(ddof=1) / math.sqrt(len(e)):.1f}) | "
            f"{sd:.4f} ({_num(sd_standard_error(e))}) | {skew:+.2f} | "
            + " | ".join(f"{f['restitution_sd']:.4f} ({_num(f['restitution_sd_se'])}) / "
                         f"{sd:.4f} = {f['restitution_sd'] / sd:.2f}"
                         for f in fc.values())
            + f" | {100 * big['restitution_error_mean']:+.1f} % | "
            f"{int(np.sum(np.abs(e - ei) <= Z95 * big['restitution_sd']))}/{len(e)} |")
        print(lines[-1], flush=True)
    return lines


def replicate_mean_run(args: tuple) -> tuple[float, float] | None:
    """One sponge hil run with its snapshot: (its restitution, the mean restitution of 30
    replicates of its contact window with the noise measured at its calibration)."""
    from app.runs.uncertainty import measured_noise, restitution_spread

    seed, reference = args
    config = configure(load_scenario("collision"), [f"loop.seed={seed}"])
    result = run_scenario(config, ideal=reference, preflight_done=True)
    em, coll = result.emulator, result.metrics["collision"] or {}
    if coll.get("restitution") is None or em.snapshot is None:
        return None
    pair = tuple(int(p[3:]) for p in coll["pair"])
    until_s = min(max(em.t_s, em.config.loop.duration_s),
                  coll["window_s"][1] + 0.5 + 2 * coll["contact_duration_s"])
    spread = restitution_spread(em.snapshot, pair, until_s, measured_noise(em), 30,
                                np.random.default_rng([seed, 99]))
    got = [e for e in spread["restitutions"] if e is not None]
    return coll["restitution"], float(np.mean(got))


def replicate_means(pool, first_seed: int, n: int) -> str:
    """The sponge: the runs' mean error against the mean error of their own replicates
    (from each run's snapshot) and of the forecast's (from the noise-free twin's)."""
    base = configure(load_scenario("collision"), [])
    config = headless_config(base, base.loop.duration_s)
    reference = checked_reference(config, config.loop.duration_s)
    ei = reference["restitution"]
    got = np.array([r for r in pool.map(replicate_mean_run,
                                        [(s, reference) for s in range(first_seed,
                                                                       first_seed + n)])
                    if r is not None])
    err = (got - ei) / ei
    se = err.std(axis=0, ddof=1) / math.sqrt(len(got))
    fc = reference["forecast"]
    fc_se = fc["restitution_sd"] / ei / math.sqrt(fc["replicates_with_restitution"])
    line = (f"| sponge vs rigid | {first_seed}-{first_seed + n - 1} ({len(got)} with e) | "
            f"{100 * err[:, 0].mean():+.1f} % ({100 * se[0]:.1f}) | "
            f"{100 * err[:, 1].mean():+.1f} % ({100 * se[1]:.1f}) | "
            f"{100 * fc['restitution_error_mean']:+.1f} % "
            f"({100 * fc_se:.1f}) |")
    print("| case | seeds | the runs' mean error (SE) | their own replicates' (30 each, from "
          "each run's snapshot) | the forecast's (from the noise-free twin) |")
    print("|---|---|---|---|---|")
    print(line, flush=True)
    return line


RIG_SENSORS = ["ur10e", "ati-gamma", "ati-mini45", "robotiq-ft300s"]
RIG_PLACEMENTS = ["flange", "mockup"]
RIG_SERVOS = ["second-order", "servoj"]
SLOW_RIGID = RIGID[:1] + ["satellites.0.velocity_mps=[0.04,0,0]",
                          "satellites.1.velocity_mps=[-0.04,0,0]", "loop.duration_s=8.7"]
"""Rigid vs rigid at half the shipped approach speed (the contact at 6.2 s): within the
acceleration the arms can give (docs/sensors.md)."""
RIG_MATERIALS = {"sponge vs rigid": [], "rigid vs rigid": RIGID,
                 "rigid vs rigid at 0.04 m/s": SLOW_RIGID}


def rig_assignments(sensor: str, placement: str, servo: str) -> list[str]:
    """The collision scenario's chain on the lab's rig: sensor model, placement, servo."""
    return [f'sensor.model="{sensor}"', f'sensor.placement="{placement}"',
            f'servo.model="{servo}"']


def rig_run(args: tuple) -> dict:
    """One hil run of the collision scenario as ``orbit-emulator run`` makes it (its
    metrics.json), against the ideal run given; with ``preflight``, its pre-flight too
    (where a forecast is made)."""
    assignments, seed, ideal, preflight = args
    config = configure(load_scenario("collision"), assignments + [f"loop.seed={seed}"])
    try:
        # with the pre-flight, its reference (the forecast with it) is the run's, as in
        # ``orbit-emulator run``; the interval's systematic part comes from that forecast
        metrics = run_scenario(config, ideal=None if preflight else ideal,
                               preflight_done=not preflight).metrics
    except Exception as err:  # a refusal (e.g. the lead beyond 100 ms) is a table cell too
        return {"error": f"{type(err).__name__}: {err}"}
    return {"collision": metrics.get("collision"),
            "forecast": metrics.get("collision_forecast"),
            "status": metrics.get("status"), "safety_stop": metrics.get("safety_stop")}


def _off_normal(coll: dict) -> float | None:
    """The share of the received impulse off the contact normal, if the metrics have it
    (the contact-measurement chain adds it)."""
    for key in ("off_normal_share", "off_normal_fraction", "off_normal_impulse_share"):
        if isinstance(coll.get(key), (int, float)):
            return float(coll[key])
    ratios = coll.get("off_normal_ratio") or {}
    values = [v for v in ratios.values() if isinstance(v, (int, float))]
    return max(values) if values else None


def rig_cell(runs: list[dict], ideal: dict) -> dict:
    """One row's figures over its seeds: restitution error, its sd, off-normal share,
    interval coverage (ideal restitution inside ``restitution_interval_95``), forecast sd
    against the across-seed sd of the restitution; None where the metric is absent."""
    colls = [r.get("collision") or {} for r in runs]
    errors = [c.get("restitution_error") for c in colls]
    values = [c.get("restitution") for c in colls if c.get("restitution") is not None]
    off = [x for x in (_off_normal(c) for c in colls) if x is not None]
    intervals = [c.get("restitution_interval_95") for c in colls]
    e_ideal = ideal.get("restitution")
    covered = None
    if any(i is not None for i in intervals) and e_ideal is not None:
        covered = sum(i is not None and i[0] <= e_ideal <= i[1] for i in intervals)
    forecasts = [f.get("restitution_sd") for f in (r.get("forecast") or {} for r in runs)
                 if isinstance(f.get("restitution_sd"), (int, float))]
    sd_seeds = statistics.stdev(values) if len(values) > 1 else None
    rendered = [c["rendering_error_m"] / c["contact_depth_m"] for c in colls
                if c.get("rendering_error_m") is not None and c.get("contact_depth_m")]
    return {"errors": errors, "off_normal": statistics.fmean(off) if off else None,
            "rendering": rendered,
            "covered": covered, "n": len(runs),
            "stops": sum(r.get("status") == "safety_stop" for r in runs),
            "refused": next((r["error"] for r in runs if "error" in r), None),
            "forecast_ratio": (statistics.fmean(forecasts) / sd_seeds
                               if forecasts and sd_seeds else None)}


def rig_table(pool, seeds: list[int], sensors=RIG_SENSORS, placements=RIG_PLACEMENTS,
              servos=RIG_SERVOS, materials=tuple(RIG_MATERIALS), preflight=False,
              assignments=()) -> list[str]:
    """Sensor model x placement x servo model x material on the collision scenario's
    chain (with ``assignments`` on top, e.g. ``compensation.enabled=false``): restitution
    error (mean, SE, sd, worst), off-normal share, interval coverage and forecast /
    across-seed sd (columns "—" while the metrics lack them)."""
    lines = ["| material | sensor | placement | servo | restitution error: mean % (SE) ± sd "
             "(worst) | within ±5 % / ±10 % | stops | off-normal share | interval holds "
             "the ideal | forecast sd / seeds' sd | rendering error / contact depth: "
             f"median (runs beyond {100 * RENDERING_TOLERANCE:g} %) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for material in materials:
        extra = RIG_MATERIALS[material]
        ideal = _ideal(extra)
        for sensor in sensors:
            for placement in placements:
                for servo in servos:
                    jobs = [(extra + rig_assignments(sensor, placement, servo)
                             + list(assignments), s, ideal, preflight) for s in seeds]
                    cell = rig_cell(pool.map(rig_run, jobs), ideal)
                    lines.append(_rig_line(material, ideal, sensor, placement, servo, cell))
                    print(lines[-1], flush=True)
    return lines


def _rig_line(material, ideal, sensor, placement, servo, cell) -> str:
    if cell["refused"]:
        return (f"| {material} | {sensor} | {placement} | {servo} | refused: "
                f"{cell['refused'][:120]} | | | | | | |")
    errs = [e for e in cell["errors"] if e is not None]
    within = (f"{sum(abs(e) <= 0.05 for e in errs)} / {sum(abs(e) <= 0.10 for e in errs)}"
              f" of {cell['n']}")
    off = "—" if cell["off_normal"] is None else f"{100 * cell['off_normal']:.1f} %"
    cov = "—" if cell["covered"] is None else f"{cell['covered']}/{cell['n']}"
    fc = "—" if cell["forecast_ratio"] is None else f"{cell['forecast_ratio']:.2f}"
    ren = cell["rendering"]
    rendered = ("—" if not ren else f"{100 * statistics.median(ren):.1f} % "
                f"({sum(r > RENDERING_TOLERANCE for r in ren)})")
    return (f"| {material} (e {ideal['restitution']:.3f}) | {sensor} | {placement} | {servo} "
            f"| {_fmt(cell['errors'])} | {within} | {cell['stops']}/{cell['n']} | {off} | "
            f"{cov} | {fc} | {rendered} |")


def free_floating(assignments: list[str]) -> dict:
    """Tracking, Δv of each force push against impulse·scale/mass, spin after them."""
    config = configure(load_scenario("free-floating-scripted"), assignments)
    em = run_scenario(config, with_ideal=False).emulator
    rows, ix = em.telemetry.rows(), em.telemetry.index
    t = rows[:, 0]
    v = rows[:, [ix["sat1_vx_mps"], ix["sat1_vy_mps"], ix["sat1_vz_mps"]]]
    w = rows[:, [ix["sat1_wx_radps"], ix["sat1_wy_radps"], ix["sat1_wz_radps"]]]
    p_err = np.linalg.norm(rows[:, [ix["rob1_x_m"], ix["rob1_y_m"], ix["rob1_z_m"]]]
                           - rows[:, [ix["sat1_x_m"], ix["sat1_y_m"], ix["sat1_z_m"]]], axis=1)
    mass, scale = config.satellites[0].mass_kg, config.orbit.force_scale
    errors = []
    force_pulses = [p for p in config.pulses if any(p.force_N)]
    for p in force_pulses:
        before = np.searchsorted(t, p.start_s - 0.05)
        after = np.searchsorted(t, p.end_s + 0.3)
        expected = np.array(p.force_N) * (p.end_s - p.start_s) * scale / mass
        dv = v[after] - v[before]
        errors.append(float(np.linalg.norm(dv - expected) / np.linalg.norm(expected)))
    last_force_end = max(p.end_s for p in force_pulses)
    first_torque = min((p.start_s for p in config.pulses if any(p.torque_Nm)), default=t[-1])
    spin = w[(t > last_force_end + 0.3) & (t < first_torque)]
    return {"status": em.status, "tracking_max_mm": 1e3 * float(p_err.max()),
            "dv_error_max": max(errors),
            "spin_max_radps": float(np.linalg.norm(spin, axis=1).max())}


def fidelity_map(pool, out_png: Path) -> list[str]:
    """Restitution error (no sensor noise) over stiffness, approach speed and added delay."""
    stiffness = [500.0, 5000.0, 50000.0]
    speeds = [0.01, 0.04, 0.1]
    delays = [0, 2, 4]  # added servo delay, cycles of 2 ms
    jobs, keys = [], []
    for k in stiffness:
        for v in speeds:
            x0 = 0.1 + 0.0015 + v * 1.0  # contact after about 1 s
            base = NO_NOISE + [
                f"materials.sponge.stiffness_Npm={k}", "loop.duration_s=3.5",
                f"satellites.0.position_m=[{-x0},0,0]", f"satellites.0.velocity_mps=[{v},0,0]",
                f"satellites.1.position_m=[{x0},0,0]", f"satellites.1.velocity_mps=[{-v},0,0]"]
            ideal = _ideal(base)
            for d in delays:
                for chain in ("paper", "compensated"):
                    extra = [f"servo.delay_cycles={1 + d}"] + (PAPER if chain == "paper" else [])
                    jobs.append((base + extra, 0, ideal))
                    keys.append((k, v, d, chain))
    results = dict(zip(keys, pool.map(collision_run, jobs), strict=True))

    def cell(key):
        r = results[key]
        text = _label(r)
        return text + " stop" if r["status"] == "safety_stop" and text != "stop" else text

    lines = ["| sponge k (N/m) | speed (m/s) | added delay (ms) | paper chain | compensated |",
             "|---|---|---|---|---|"]
    for k in stiffness:
        for v in speeds:
            for d in delays:
                lines.append(f"| {k:g} | {v:g} | {2 * d} | {cell((k, v, d, 'paper'))} | "
                             f"{cell((k, v, d, 'compensated'))} |")
    _heat_map(results, stiffness, speeds, delays, out_png)
    return lines


def _label(run: dict) -> str:
    """A map cell: the restitution error, or why there is none ("stuck": still touching
    when the run ended; "no parting": not moving apart after the contact; "stop": a
    safety stop first); "*": the bodies touched again later (the figure is the first
    contact's)."""
    c = run["collision"]
    again = "*" if c and any("touched again" in w for w in c["warnings"]) else ""
    if c and c["restitution_error"] is not None:
        return f"{100 * c['restitution_error']:+.0f} %{again}"
    if run["status"] == "safety_stop":
        return "stop"
    if not c:
        return "—"
    return ("stuck" if c["contact_open_at_end"] else "no parting") + again


def _heat_map(results, stiffness, speeds, delays, out_png: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(delays), figsize=(4.2 * len(delays) + 1.5, 7.5),
                             squeeze=False, constrained_layout=True)
    for row, chain in enumerate(("paper", "compensated")):
        for col, d in enumerate(delays):
            grid = np.full((len(stiffness), len(speeds)), np.nan)
            labels = {}
            for i, k in enumerate(stiffness):
                for j, v in enumerate(speeds):
                    r = results[(k, v, d, chain)]
                    c = r["collision"]
                    if c and c["restitution_error"] is not None:
                        grid[i, j] = 100 * c["restitution_error"]
                    labels[(k, v)] = _label(r)
            ax = axes[row, col]
            im = ax.imshow(np.clip(grid, -100, 100), cmap="RdBu_r", vmin=-100, vmax=100,
                           origin="lower")
            for i, k_ in enumerate(stiffness):
                for j, v_ in enumerate(speeds):
                    text = labels[(k_, v_)].replace(" %", "")
                    dark = not math.isnan(grid[i, j]) and abs(grid[i, j]) > 60
                    ax.text(j, i, text, ha="center", va="center", fontsize=9,
                            color="white" if dark else "black")
            ax.set_xticks(range(len(speeds)), [f"{v:g}" for v in speeds])
            ax.set_yticks(range(len(stiffness)), [f"{k:g}" for k in stiffness])
            ax.set_xlabel("speed of each satellite (m/s)")
            if col == 0:
                ax.set_ylabel("sponge stiffness (N/m)")
            ax.set_title(f"{chain}, +{2 * d} ms delay", fontsize=10)
    fig.colorbar(im, ax=axes, label="restitution error (%), clipped at ±100")
    fig.suptitle("Restitution error of the emulated collision vs the converged ideal "
                 "(sensor noise off, seed 0)")
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=72)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="seed 0 only")
    parser.add_argument("--map", action="store_true", help="also the fidelity map")
    parser.add_argument("--png", default="benchmarks/fidelity_map.png")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rig-table", action="store_true",
                        help="instead: sensor model x placement x servo model x material "
                             "(docs/sensors.md)")
    parser.add_argument("--rig-seeds", type=int, default=10,
                        help="with --rig-table: seeds 0..N-1")
    parser.add_argument("--sensor", action="append", choices=RIG_SENSORS,
                        help="with --rig-table: only these sensor models (repeatable)")
    parser.add_argument("--placement", action="append", choices=RIG_PLACEMENTS)
    parser.add_argument("--servo", action="append", choices=RIG_SERVOS)
    parser.add_argument("--material", action="append", choices=list(RIG_MATERIALS))
    parser.add_argument("--preflight", action="store_true",
                        help="with --rig-table: run each run's pre-flight too (its forecast)")
    parser.add_argument("--calibration", type=int, metavar="SEEDS", default=None,
                        help="instead: the compensated sponge over SEEDS seeds with the bias "
                             "calibration averaged over 0.5 s and over 2 s (the default)")
    parser.add_argument("--calibration-check", action="store_true",
                        help="instead: the restitution's 95 %% interval and the pre-flight's "
                             "forecast against the spread over seeds (sponge 0-29, rigid "
                             "0-19)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="with --calibration-check or --rig-table: a setting for every run")
    parser.add_argument("--seeds", action="store_true",
                        help="instead: the shipped collision over 30 (sponge) and 20 (rigid) "
                             "seeds, without and with noise")
    parser.add_argument("--factors", action="store_true",
                        help="with --seeds: each bias factor's share")
    parser.add_argument("--factor", action="append", choices=list(FACTORS),
                        help="with --seeds --factors: only these factors (repeatable)")
    parser.add_argument("--mismatch", type=int, metavar="SEEDS", default=None,
                        help="instead: the collision with contacts the lab's model does not "
                             "describe (Hertz law, mockups larger than drawn, friction), "
                             "SEEDS seeds from --first-seed")
    parser.add_argument("--sponge-seeds", type=int, default=None, metavar="N",
                        help="with --seeds: N sponge seeds instead of 30 (a shorter try)")
    parser.add_argument("--rigid-seeds", type=int, default=None, metavar="N",
                        help="with --seeds: N rigid seeds instead of 20")
    parser.add_argument("--no-perfect-emulator", action="store_true",
                        help="with --seeds: skip the perfect emulator + noise table")
    parser.add_argument("--pool", type=int, metavar="SEEDS", default=None,
                        help="instead: SEEDS seeds per case from --first-seed without "
                             "intervals, against the forecast with 60, 200 and 600 "
                             "replicates")
    parser.add_argument("--replicate-means", type=int, metavar="SEEDS", default=None,
                        help="instead: the sponge's runs' mean error against their own "
                             "replicates' and the forecast's, over SEEDS seeds")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="with --seeds, --calibration-check or --rig-table: the first "
                             "seed (1000: the chain's tuning seeds)")
    args = parser.parse_args()
    seeds = [0] if args.quick else SEEDS
    t0 = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        if args.rig_table:
            first, last = args.first_seed, args.first_seed + args.rig_seeds - 1
            print(f"## The lab's rig (collision scenario, seeds {first}-{last}"
                  + (f"; {' '.join(args.set)}" if args.set else "") + ")\n")
            rig_table(pool, list(range(first, last + 1)), args.sensor or RIG_SENSORS,
                      args.placement or RIG_PLACEMENTS, args.servo or RIG_SERVOS,
                      args.material or list(RIG_MATERIALS), args.preflight, args.set)
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        if args.calibration_check or args.seeds:
            if args.calibration_check:
                cases = {case: (extra, [args.first_seed + s for s in seeds])
                         for case, (extra, seeds) in CHECK_CASES.items()}
                calibration_check(pool, cases, assignments=args.set)
            else:
                counts = {case: n for case, n in (("sponge vs rigid", args.sponge_seeds),
                                                  ("rigid vs rigid", args.rigid_seeds))
                          if n is not None}
                seeds_table(pool, args.first_seed,
                            (args.factor or True) if args.factors else False, counts)
                if not args.no_perfect_emulator:
                    noisy_ideal_table(pool, args.first_seed)
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        if args.mismatch:
            mismatch_table(pool, args.first_seed, args.mismatch)
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        if args.replicate_means:
            replicate_means(pool, args.first_seed, args.replicate_means)
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        if args.pool:
            spread_pool(pool, args.first_seed, args.pool)
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        if args.calibration:
            calibration_table(pool, list(range(args.calibration)))
            print(f"\n({time.perf_counter() - t0:.0f} s)")
            return
        print("## Collision (500 Hz, seeds " + ", ".join(map(str, seeds)) + ")\n")
        collision_table(pool, seeds)
        print("\n## Free-floating\n")
        print("| chain | status | tracking max | worst push Δv error | spin after force pushes |")
        print("|---|---|---|---|---|")
        for name, assignments in (("paper", ["compensation.enabled=false"]),
                                  ("compensated", ["compensation.enabled=true"])):
            f = free_floating(assignments)
            print(f"| {name} | {f['status']} | {f['tracking_max_mm']:.3f} mm | "
                  f"{100 * f['dv_error_max']:.2f} % | {f['spin_max_radps']:.2e} rad/s |")
        if args.map:
            print("\n## Fidelity map (sensor noise off, seed 0)\n")
            for line in fidelity_map(pool, Path(args.png)):
                print(line)
            print(f"\nwrote {args.png}")
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
