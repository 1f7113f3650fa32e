"""Does this tree give the same telemetry as another checkout? (a check for refactorings)

    git worktree add /tmp/old <commit>
    .venv/bin/python -m benchmarks.same_telemetry --against /tmp/old

Runs a fixed set of headless cases (scenario, mode, seed, settings) in a fresh process for
each tree and compares the recorded telemetry rows bit for bit (and the metrics, less the
timing figures). Needs only ``app.runs.headless.run_scenario``, ``app.config.merge_overrides``
and ``app.scenarios.load_scenario`` in the other tree.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]

CASES = {
    "collision hil seed 0": ("collision", "hil", {}, None),
    "collision hil seed 3": ("collision", "hil", {"loop": {"seed": 3}}, None),
    "collision ideal": ("collision", "ideal", {}, None),
    "collision hil, passivity off (safety stop)": (
        "collision", "hil", {"passivity": {"enabled": False}}, None),
    "collision hil, VFDM reset + PD, 4 s": (
        "collision", "hil",
        {"vfdm": {"velocity_mode": "reset", "kd_lin": 0.5, "kd_rot": 0.1}}, 4.0),
    "free-floating-scripted hil": ("free-floating-scripted", "hil", {}, None),
    "free-floating-scripted ideal": ("free-floating-scripted", "ideal", {}, None),
}


def shipped_cases(duration_s: float = 4.0) -> dict:
    """``--all-scenarios``: every shipped scenario (app/scenarios/*.toml), hil and ideal,
    the first ``duration_s`` of each, besides CASES."""
    names = sorted(p.stem for p in (ROOT / "app" / "scenarios").glob("*.toml"))
    return {f"{name} {mode}, {duration_s:g} s": (name, mode, {}, duration_s)
            for name in names for mode in ("hil", "ideal")}


def record(out_dir: Path, cases: dict) -> None:
    """Run every case in this process; write rows (.npy) and metrics (.json) per case."""
    import app
    from app.config import merge_overrides
    from app.runs.headless import run_scenario
    from app.scenarios import load_scenario

    print(f"recording with {Path(app.__file__).parent}", flush=True)

    for k, (scenario, mode, overrides, duration) in enumerate(cases.values()):
        config = merge_overrides(load_scenario(scenario), overrides)
        r = run_scenario(config, mode=mode, duration_s=duration)
        np.save(out_dir / f"{k}.npy", r.emulator.telemetry.rows())
        metrics = {k2: v for k2, v in r.metrics.items()
                   if k2 not in ("realtime_factor", "cycle_time_us")}
        (out_dir / f"{k}.json").write_text(json.dumps(metrics, sort_keys=True))


def _record_in(tree: Path, out_dir: Path, every: bool) -> None:
    env = dict(os.environ, PYTHONPATH=str(tree))
    subprocess.run([sys.executable, str(HERE), "--record", str(out_dir),
                    *(["--all-scenarios"] if every else [])], env=env, cwd=tree, check=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, help="the other checkout")
    ap.add_argument("--all-scenarios", action="store_true",
                    help="also every shipped scenario, hil and ideal, 4 s each")
    ap.add_argument("--record", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    cases = {**CASES, **shipped_cases()} if args.all_scenarios else CASES
    if args.record:
        record(args.record, cases)
        return 0
    if args.against is None:
        ap.error("--against TREE is needed")
    with tempfile.TemporaryDirectory() as tmp:
        this, that = Path(tmp, "this"), Path(tmp, "that")
        this.mkdir()
        that.mkdir()
        _record_in(ROOT, this, args.all_scenarios)
        _record_in(args.against.resolve(), that, args.all_scenarios)
        print("| case | rows | telemetry | metrics |")
        print("|---|---:|---|---|")
        same_all = True
        for k, name in enumerate(cases):
            a, b = np.load(this / f"{k}.npy"), np.load(that / f"{k}.npy")
            same_rows = a.shape == b.shape and a.tobytes() == b.tobytes()
            same_metrics = (this / f"{k}.json").read_text() == (that / f"{k}.json").read_text()
            if not same_rows and a.shape == b.shape:
                rows = f"differs, max |Δ| {np.abs(a - b).max():.3g}"
            else:
                rows = "bit-identical" if same_rows else f"shape {a.shape} vs {b.shape}"
            print(f"| {name} | {len(a)} | {rows} | {'equal' if same_metrics else 'DIFFER'} |")
            same_all &= same_rows and same_metrics
    print("\nall identical" if same_all else "\nDIFFERENCES FOUND")
    return 0 if same_all else 1


if __name__ == "__main__":
    raise SystemExit(main())
