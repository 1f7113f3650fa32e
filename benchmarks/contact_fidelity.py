"""How faithful is an emulated contact? HIL runs against the converged ideal reference.

    .venv/bin/python -m benchmarks.contact_fidelity             # the table (seeds 0-4)
    .venv/bin/python -m benchmarks.contact_fidelity --map       # + the fidelity map (PNG)
    .venv/bin/python -m benchmarks.contact_fidelity --quick     # seed 0 only
    .venv/bin/python -m benchmarks.contact_fidelity --calibration 30   # bias calibration
    .venv/bin/python -m benchmarks.contact_fidelity --rig-table --seeds 10   # the lab's rig

Each figure is of a whole headless run (`orbit-emulator run`), measured against the ideal
run of the same configuration (contact integrated within the ODS step: app/sim/reference.py).
Chains compared, all on the same simulated hardware (F/T noise and bias, sensor and servo
delays, servo bandwidth and limits):

* ``paper``: the paper's chain (payload + inertial compensation, 30 Hz low-pass, 4 N
  deadband), nothing else;
* ``passivity``: + the passivity layer alone (the landed default before lag compensation);
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
from app.headless import ideal_collision, run_scenario
from app.metrics import compare_with_ideal, sensing_limits
from app.scenarios import load_scenario

SEEDS = list(range(10))
"""Ten seeds: the sponge's single-run spread is ±40 %, so the mean of ten is known to about
±13 % (its standard error, printed beside it)."""
RIGID = ['satellites.1.material="rigid"', "loop.duration_s=7"]
"""7 s: an impact at the physics' e = 0.95 sends the satellites back out at 0.076 m/s, and
by 12 s they would be at the arms' bases (a workspace stop, not a fidelity figure)."""
PAPER = ["compensation.enabled=false", "wrench.contact_gate=false",
         "wrench.fuse_pair_contact=false", "passivity.enabled=false"]
PASSIVITY = PAPER[:-1] + ["passivity.enabled=true"]
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
    from app.metrics import collision_metrics
    bodies = {arm.satellite + 1: f"rob{arm.index + 1}" for arm in em.arms}
    coll = collision_metrics(em.telemetry.rows(), em.telemetry.index, em.dt_s, bodies=bodies)
    if coll is not None:
        compare_with_ideal(coll, ideal, *sensing_limits(em))
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


RIG_SENSORS = ["ur10e", "ati-gamma", "ati-mini45", "robotiq-ft300s"]
RIG_PLACEMENTS = ["flange", "mockup"]
RIG_SERVOS = ["second-order", "servoj"]
RIG_MATERIALS = {"sponge vs rigid": [], "rigid vs rigid": RIGID}


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
        metrics = run_scenario(config, ideal=ideal, preflight_done=not preflight).metrics
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
    for key, value in coll.items():
        if "off_normal" in key and isinstance(value, (int, float)):
            return float(value)
    return None


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
    return {"errors": errors, "off_normal": statistics.fmean(off) if off else None,
            "covered": covered, "n": len(runs),
            "stops": sum(r.get("status") == "safety_stop" for r in runs),
            "refused": next((r["error"] for r in runs if "error" in r), None),
            "forecast_ratio": (statistics.fmean(forecasts) / sd_seeds
                               if forecasts and sd_seeds else None)}


def rig_table(pool, seeds: list[int], sensors=RIG_SENSORS, placements=RIG_PLACEMENTS,
              servos=RIG_SERVOS, materials=tuple(RIG_MATERIALS), preflight=False
              ) -> list[str]:
    """Sensor model x placement x servo model x material on the collision scenario's
    chain: restitution error (mean, SE, sd, worst), off-normal share, interval coverage and
    forecast / across-seed sd (columns "—" while the metrics lack them)."""
    lines = ["| material | sensor | placement | servo | restitution error: mean % (SE) ± sd "
             "(worst) | within ±5 % / ±10 % | stops | off-normal share | interval holds "
             "the ideal | forecast sd / seeds' sd |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for material in materials:
        extra = RIG_MATERIALS[material]
        ideal = _ideal(extra)
        for sensor in sensors:
            for placement in placements:
                for servo in servos:
                    jobs = [(extra + rig_assignments(sensor, placement, servo), s, ideal,
                             preflight) for s in seeds]
                    cell = rig_cell(pool.map(rig_run, jobs), ideal)
                    lines.append(_rig_line(material, ideal, sensor, placement, servo, cell))
                    print(lines[-1], flush=True)
    return lines


def _rig_line(material, ideal, sensor, placement, servo, cell) -> str:
    if cell["refused"]:
        return (f"| {material} | {sensor} | {placement} | {servo} | refused: "
                f"{cell['refused'][:120]} | | | | | |")
    errs = [e for e in cell["errors"] if e is not None]
    within = (f"{sum(abs(e) <= 0.05 for e in errs)} / {sum(abs(e) <= 0.10 for e in errs)}"
              f" of {cell['n']}")
    off = "—" if cell["off_normal"] is None else f"{100 * cell['off_normal']:.1f} %"
    cov = "—" if cell["covered"] is None else f"{cell['covered']}/{cell['n']}"
    fc = "—" if cell["forecast_ratio"] is None else f"{cell['forecast_ratio']:.2f}"
    return (f"| {material} (e {ideal['restitution']:.3f}) | {sensor} | {placement} | {servo} "
            f"| {_fmt(cell['errors'])} | {within} | {cell['stops']}/{cell['n']} | {off} | "
            f"{cov} | {fc} |")


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
    parser.add_argument("--seeds", type=int, default=10, help="with --rig-table: seeds 0..N-1")
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
    args = parser.parse_args()
    seeds = [0] if args.quick else SEEDS
    t0 = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        if args.rig_table:
            print(f"## The lab's rig (collision scenario, seeds 0-{args.seeds - 1})\n")
            rig_table(pool, list(range(args.seeds)), args.sensor or RIG_SENSORS,
                      args.placement or RIG_PLACEMENTS, args.servo or RIG_SERVOS,
                      args.material or list(RIG_MATERIALS), args.preflight)
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
