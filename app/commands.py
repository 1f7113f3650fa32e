"""The `run`, `scenarios` and `serve` subcommands of `orbit-emulator`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.config import assignment_override, load_config, merge_overrides
from app.scenarios import scenario_descriptions, scenario_names


def _positive(text: str) -> float:
    from app.cli import _positive_float

    return _positive_float(text)


def _cmd_scenarios(args: argparse.Namespace) -> int:
    for name, desc in scenario_descriptions().items():
        print(f"{name:15s} {desc}")
    return 0


def _summary(metrics: dict) -> str:
    lines = [
        f"scenario {metrics['scenario']}  mode {metrics['mode']}  status {metrics['status']}",
        f"simulated {metrics['duration_s']:.2f} s in {metrics['cycles']} cycles, "
        f"real-time factor {metrics['realtime_factor']:.2f}, cycle p50 "
        f"{metrics['cycle_time_us']['p50']:.0f} us / p99 {metrics['cycle_time_us']['p99']:.0f} us",
        f"force scale {metrics['force_scale']:g}, torque scale {metrics['torque_scale']:g}",
        "",
        f"{'sat':>3} {'name':12s} {'pos err max':>12} {'pos err rms':>12} {'vel err rms':>12} "
        f"{'att err max':>12} {'delta v':>10}",
    ]

    def fmt(v, scale=1.0, unit=""):
        return f"{v * scale:10.3f}{unit}" if v is not None else f"{'-':>12}"

    for s in metrics["satellites"]:
        lines.append(
            f"{s['id']:>3} {s['name']:12s} {fmt(s['position_error_max_m'], 1e3, 'mm')} "
            f"{fmt(s['position_error_rms_m'], 1e3, 'mm')} "
            f"{fmt(s['velocity_error_rms_mps'], 1e3, 'mm/s')[:-2]:>12} "
            f"{fmt(s['attitude_error_max_rad'], 1e3, 'mr')} {s['delta_v_mps']:8.4f}m/s"
        )
    coll = metrics.get("collision")
    if coll:
        e, ei = coll["restitution"], coll["restitution_ideal"]
        lines += [
            "",
            f"collision at {coll['contact_start_s']:.3f} s: impulse balance "
            f"{coll['impulse_balance']:.3f}, restitution "
            f"{'-' if e is None else f'{e:.3f}'} (ideal {'-' if ei is None else f'{ei:.3f}'})",
        ]
    pc = metrics.get("passivity")
    if pc:
        removed = sum(d["force"] + d["torque"] for d in pc["dissipated_J"].values())
        lines.append(f"passivity controller removed {removed * 1e3:.2f} mJ")
    stop = metrics.get("safety_stop")
    if stop:
        lines.append(
            f"SAFETY STOP: robot {stop['robot']} at t = {stop['t_s']:.3f} s: {stop['reason']}"
        )
    return "\n".join(lines)


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from app.headless import run_scenario
    from app.scenarios import load_scenario

    config = load_config(args.config) if args.config else load_scenario(args.scenario)
    overrides: dict = {"loop": {}}
    if args.seed is not None:
        overrides["loop"]["seed"] = args.seed
    config = merge_overrides(config, overrides)
    for assignment in args.set:
        config = merge_overrides(config, assignment_override(assignment))
    duration = args.duration or config.loop.duration_s
    bar = tqdm(total=int(round(duration * config.loop.rate_hz)), unit="cycle",
               disable=args.quiet, file=sys.stderr)

    def progress(k, n):
        bar.update(k - bar.n)

    result = run_scenario(config, mode=args.mode, duration_s=duration, out_dir=default_out(args),
                          progress=progress)
    bar.update(bar.total - bar.n)
    bar.close()
    print(_summary(result.metrics))
    print(f"\nwrote {', '.join(str(p) for p in result.files)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("run", help="run a scenario headless: telemetry, metrics and plots")
    p.add_argument("scenario", choices=scenario_names(), metavar="SCENARIO",
                   help=f"one of: {', '.join(scenario_names())}")
    p.add_argument("--mode", choices=("hil", "ideal"), default=None,
                   help="hil: arms in the loop (default); ideal: the reference without arms")
    p.add_argument("--duration", type=_positive, default=None, help="seconds of scenario time")
    p.add_argument("--config", help="TOML file replacing the scenario's configuration")
    p.add_argument("--seed", type=int, default=None, help="seed of the sensor noise")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set passivity.enabled=false "
                        "or --set robots.1.q_home_rad=[0,-2,1.6,0.4,-1.57,0] (repeatable)")
    p.add_argument("--out", default=None, help="output directory (default: runs/SCENARIO)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("scenarios", help="list the built-in scenarios")
    p.set_defaults(func=_cmd_scenarios)

    from app.backend.cli import register_serve

    register_serve(sub)


def default_out(args: argparse.Namespace) -> Path:
    return Path(args.out or f"runs/{args.scenario}")
