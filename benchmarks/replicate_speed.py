"""Replicate benchmark: the cost of the uncertainty's replicates of a contact window.

    .venv/bin/python -m benchmarks.replicate_speed                     # this tree
    .venv/bin/python -m benchmarks.replicate_speed --quick             # small counts (smoke)
    .venv/bin/python -m benchmarks.replicate_speed --against /tmp/old  # both trees, ratio

Two settings: the shipped collision (hil, its own 8 s; its sponge is 500 N/m, the soft
setting of a campaign's stiffness sweep) and the sweep's stiff setting
(``materials.sponge.stiffness_Npm = 8000``, 3.5 s: a shorter contact). For each, two timed calls of
app/runs/uncertainty.py, as a run calls them:

* the pre-flight's forecast, ``forecast(config, ideal)`` (its noise-free twin run to the
  snapshot, then ``[uncertainty] forecast_replicates`` replicates, 200 by default);
* a run's interval, ``spread_of_run(em, coll)`` after a hil run that kept its snapshot
  (``[uncertainty] replicates``, 30 by default).

Printed per call: its wall time, and of the replicates alone (``restitution_spread``) the
time per replicate and per replicate cycle (a replicate steps only the contact window, so
its cycles are in or next to contact). The set-up (the pre-flight's ideal run, the hil run)
is not timed.

Each tree runs in a worker process of its own (``PYTHONPATH`` the tree's), set up once;
with ``--against TREE`` the rounds alternate between the two workers, so that both see the
same machine, and each round gives a ratio. The outputs are compared as well: the
replicates' restitutions, and the whole forecast and interval (JSON): a change meant to be
faster only must leave them bit-identical.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]

SETTINGS = {
    "collision (shipped, sponge 500 N/m)": ({}, None),
    "stiff contact (sponge 8000 N/m, 3.5 s)": (
        {"materials": {"sponge": {"stiffness_Npm": 8000}}}, 3.5),
}
QUICK = {"uncertainty": {"forecast_replicates": 6, "replicates": 4}}


# --- the worker (runs in the tree measured) -------------------------------------------------


class _Counter:
    """Counts the cycles the replicates step: every copy of the loop (``copy_state``)
    remembers where it started, and its ``record_final`` (a replicate's last call) adds the
    cycles it stepped since."""

    def __init__(self, Emulator) -> None:
        self.cycles = 0
        self.replicates = 0
        self._start: dict[int, int] = {}
        copy_state, record_final = Emulator.copy_state, Emulator.record_final
        counter = self

        def counted_copy(em, *args, **kwargs):
            twin = copy_state(em, *args, **kwargs)
            counter._start[id(twin)] = twin.cycles
            return twin

        def counted_final(em, *args, **kwargs):
            start = counter._start.pop(id(em), None)
            if start is not None:
                counter.cycles += em.cycles - start
                counter.replicates += 1
            return record_final(em, *args, **kwargs)

        Emulator.copy_state, Emulator.record_final = counted_copy, counted_final


class _Setting:
    """One setting, set up: its ideal run's collision (the forecast's input) and a hil run
    that kept its snapshot (the interval's)."""

    def __init__(self, overrides: dict, duration_s: float | None, quick: bool) -> None:
        import app.runs.headless as headless
        from app.config import merge_overrides
        from app.runs.preflight import preflight
        from app.scenarios import load_scenario

        config = merge_overrides(load_scenario("collision"), overrides)
        if quick:
            config = merge_overrides(config, QUICK)
        duration_s = duration_s or config.loop.duration_s
        self.config = headless.headless_config(config, duration_s)
        self.ideal = headless.collision_of(preflight(self.config, duration_s))
        spread_of_run = headless.spread_of_run
        headless.spread_of_run = lambda em, coll, tick=None: None  # timed below, not here
        try:
            run = headless.run_scenario(self.config, mode="hil", duration_s=duration_s,
                                        ideal=self.ideal, preflight_done=True)
        finally:
            headless.spread_of_run = spread_of_run
        self.em, self.coll = run.emulator, run.metrics["collision"]


def _timed(uncertainty, counter: _Counter, call) -> dict:
    """Time ``call()``, and within it the replicates (``restitution_spread``): their count,
    their cycles and their restitutions."""
    spread = uncertainty.restitution_spread
    got = {}

    def timed_spread(*args, **kwargs):
        c0, r0 = counter.cycles, counter.replicates
        t0, cpu0 = time.perf_counter(), time.process_time()
        out = spread(*args, **kwargs)
        got.update(spread_s=time.perf_counter() - t0, spread_cpu_s=time.process_time() - cpu0,
                   cycles=counter.cycles - c0,
                   replicates=counter.replicates - r0, restitutions=out["restitutions"])
        return out

    uncertainty.restitution_spread = timed_spread
    try:
        t0 = time.perf_counter()
        result = call()
        got["total_s"] = time.perf_counter() - t0
    finally:
        uncertainty.restitution_spread = spread
    got["result"] = json.dumps(result, sort_keys=True, default=repr)
    return got


def worker(quick: bool) -> None:
    """Read "<setting>\\t<forecast|interval>" lines from stdin, answer each with one JSON
    line: its timings and outputs (``_timed``)."""
    import app.runs.uncertainty as uncertainty
    from app.sim.loop import Emulator

    counter = _Counter(Emulator)
    settings: dict[str, _Setting] = {}
    print(json.dumps({"ready": str(Path(uncertainty.__file__).parents[2])}), flush=True)
    for line in sys.stdin:
        name, what = line.rstrip("\n").split("\t")
        if name not in settings:
            settings[name] = _Setting(*SETTINGS[name], quick)
        call = _forecast if what == "forecast" else _interval
        print(json.dumps(_timed(uncertainty, counter, call(uncertainty, settings[name]))),
              flush=True)


def _forecast(uncertainty, s: _Setting):
    """The pre-flight's call: the forecast of the setting."""
    return lambda: uncertainty.forecast(s.config, s.ideal)


def _interval(uncertainty, s: _Setting):
    """The run's call: its interval from its snapshot (on a fresh copy of its metrics)."""
    coll = copy.deepcopy(s.coll)
    return lambda: (uncertainty.spread_of_run(s.em, coll), coll)[1]


# --- the driver ---------------------------------------------------------------------------


class Worker:
    """A worker process of ``tree``."""

    def __init__(self, tree: Path, quick: bool) -> None:
        env = dict(os.environ, PYTHONPATH=str(tree))
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE), "--worker", *(["--quick"] if quick else [])],
            cwd=tree, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.tree = json.loads(self._line())["ready"]

    def _line(self) -> str:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the worker exited ({self.proc.wait()})")
        return line

    def ask(self, setting: str, what: str) -> dict:
        self.proc.stdin.write(f"{setting}\t{what}\n")
        self.proc.stdin.flush()
        return json.loads(self._line())

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def _row(name: str, what: str, tree: str, got: dict) -> str:
    n, cycles = max(got["replicates"], 1), max(got["cycles"], 1)
    return (f"| {name} | {what} | {tree} | {got['total_s']:.2f} | {got['replicates']} | "
            f"{got['cycles'] / n:.0f} | {1e3 * got['spread_s'] / n:.1f} | "
            f"{1e3 * got['spread_cpu_s'] / n:.1f} | {1e6 * got['spread_s'] / cycles:.0f} | "
            f"{1e6 * got['spread_cpu_s'] / cycles:.0f} |")


def measure(trees: dict[str, Path], rounds: int, quick: bool) -> int:
    workers = {name: Worker(tree, quick) for name, tree in trees.items()}
    results: dict[tuple, list[dict]] = {}
    try:
        for setting in SETTINGS:  # set up (and warm) each worker before the timed rounds
            for w in workers.values():
                w.ask(setting, "interval")
        for _ in range(rounds):
            for setting in SETTINGS:
                for what in ("forecast", "interval"):
                    for name, w in workers.items():
                        results.setdefault((setting, what, name), []).append(
                            w.ask(setting, what))
    finally:
        for w in workers.values():
            w.close()
    names = list(trees)
    print(f"\n## Replicates: {rounds} round(s){', alternating' if len(names) > 1 else ''} "
          f"(load {os.getloadavg()[0]:.2f}{', quick' if quick else ''})\n")
    print("| setting | call | tree | wall s | replicates | cycles / replicate | "
          "ms / replicate | CPU ms / replicate | µs / replicate cycle | CPU µs / cycle |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for (setting, what, name), got in results.items():
        for g in got:
            print(_row(setting, what, name, g))
    same_all = True
    if len(names) > 1:
        print(f"\n{names[0]} / {names[1]}, the replicates' time (wall; CPU: the process's "
              "own, less sensitive to other processes on a shared machine)\n")
        print("| setting | call | wall ratio (rounds) | median | CPU ratio (rounds) | median | "
              "restitutions identical | output identical |")
        print("|---|---|---|---:|---|---:|---|---|")
        for setting in SETTINGS:
            for what in ("forecast", "interval"):
                a, b = (results[(setting, what, n)] for n in names)
                pairs = list(zip(a, b, strict=True))
                ratios = [x["spread_s"] / y["spread_s"] for x, y in pairs]
                cpu = [x["spread_cpu_s"] / y["spread_cpu_s"] for x, y in pairs]
                same_e = all(x["restitutions"] == y["restitutions"] for x, y in pairs)
                same_out = all(x["result"] == y["result"] for x, y in pairs)
                same_all &= same_e and same_out
                print(f"| {setting} | {what} | {', '.join(f'{r:.2f}' for r in ratios)} | "
                      f"{statistics.median(ratios):.2f} | "
                      f"{', '.join(f'{r:.2f}' for r in cpu)} | {statistics.median(cpu):.2f} | "
                      f"{'yes' if same_e else 'NO'} | {'yes' if same_out else 'NO'} |")
        print("\nall identical" if same_all else "\nDIFFERENCES FOUND")
    return 0 if same_all else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, default=None, help="another checkout")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quick", action="store_true",
                    help=f"small replicate counts ({QUICK['uncertainty']}), one round")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(args.quick)
        return 0
    trees = {"this tree": ROOT}
    if args.against is not None:
        trees[str(args.against)] = args.against.resolve()
    return measure(trees, 1 if args.quick else args.rounds, args.quick)


if __name__ == "__main__":
    sys.exit(main())
