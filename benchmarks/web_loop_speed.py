"""The web loop's cycle with the page and its 3D viewer open: this tree against another.

    .venv/bin/python -m benchmarks.web_loop_speed --against /tmp/old            # 3 rounds
    .venv/bin/python -m benchmarks.web_loop_speed --against /tmp/old --rounds 1 --window-s 20
    .venv/bin/python -m benchmarks.web_loop_speed --against /tmp/old --parts 20  # loop alone

For each tree in turn (this one, then ``--against``'s, alternating over ``--rounds``) it
starts that tree's web app (``python -m app.cli serve --port 0``, with the tree on
``PYTHONPATH``, its runs in a temporary folder of its own), opens the control page in
Debian's headless Chromium (the page embeds the viser 3D viewer; it waits until the viewer
has drawn its canvas), and then, through the REST API as the page's Start does:

* **free-floating** (the page's hand-driven scenario: nothing scripted): started, a
  ``--warmup-s`` warm-up, then a ``--window-s`` window;
  (before it, the page's fidelity forecast of the scenario it shows first, the
  collision, is waited for: the web process computes it once per setting when a page
  loads, seconds of CPU that belong to no steady state)
* **collision** (unless ``--no-collision``): the shipped 8 s run, whole (it cannot run
  60 s: its satellites leave the arms' reach at 26 s).

What is read is what both trees' ``/api/state`` expose (``loop`` of the loop process's
snapshot): ``cycles`` and ``deadline_misses`` (counters: the window's are differences),
and ``cycle_time_us`` p50 / p99, which the loop process keeps over its last 5000 cycles
(10 s at 500 Hz) and refreshes every 250. The window's p50 and p99 are therefore the
medians of the six 10 s windows' p50 and p99 read 10 s apart (the collision's: its final
snapshot's, over its 4000 cycles). A cycle's time is the loop's own ``Emulator.step``
time (perf_counter around it in app/backend/loop_process.py); a deadline miss is a cycle
that ended after its period. Also printed: the CPU the web process, the loop process and
Chromium took in the window (their share of one core), the host's steal, and the
load average (1 min) as the row ended: the machine is shared, compare ratios only.

Everything goes to 127.0.0.1; servers and browsers are stopped at the end (also on
error). A round costs about ``2 * (warm-up + window + 40 s)``.

``--parts SECONDS`` instead runs each tree's loop process body alone (its ``LoopCore``
in a fresh process of that tree, no web process, no browser, no spin before a cycle):
the step's p50 / p99 / mean, the same run's steps back to back and unpaced (a headless
run's cycle, in the same process right after), the process's CPU per period, what of it
is not the step (between cycles: polling the pipe, the heartbeat, the snapshots, the
pacing), and one snapshot's cost.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
TIMING_WINDOW_S = 10.0  # the loop process's percentile window: 5000 cycles at 500 Hz
TICK_S = os.sysconf("SC_CLK_TCK")


# --- processes ------------------------------------------------------------------------


def start_server(tree: Path, runs_dir: str, cache_dir: str) -> tuple[subprocess.Popen, str]:
    """``tree``'s web app on a free loopback port and its URL (its output is drained).
    ``cache_dir``: the tree's own forecast and numba caches for the benchmark (its first
    start compiles the kernels; nothing is written into the trees)."""
    env = dict(os.environ, PYTHONPATH=str(tree), ORBIT_EMULATOR_CACHE=cache_dir,
               NUMBA_CACHE_DIR=os.path.join(cache_dir, "numba"))
    env.pop("ORBIT_EMULATOR_TOKEN", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "serve", "--port", "0", "--runs-dir", runs_dir],
        cwd=tree, env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 180
    lines = []
    for line in proc.stdout:
        lines.append(line)
        match = re.search(r"web app\s+(http://127\.0\.0\.1:\d+)/", line)
        if match:
            threading.Thread(target=lambda: proc.stdout.read(), daemon=True).start()
            return proc, match.group(1)
        if time.monotonic() > deadline:
            break
    stop_server(proc)
    raise RuntimeError(f"{tree}: the server did not print its URL:\n{''.join(lines[-20:])}")


def stop_server(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def cpu_ticks(pid: int) -> int:
    """utime + stime of one process so far (clock ticks; 0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return int(fields[11]) + int(fields[12])
    except (OSError, IndexError):
        return 0


def descendants(root: int) -> list[int]:
    """The processes below ``root`` (from /proc's parent links)."""
    parent = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    parent[int(entry)] = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    found, frontier = [], [root]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        frontier += kids
    return found


def chromium_pids() -> list[int]:
    """Chromium's processes started by this benchmark (under its Playwright driver)."""
    pids = []
    for pid in descendants(os.getpid()):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as cmd:
                if b"chromium" in cmd.read().split(b"\0")[0]:
                    pids.append(pid)
        except OSError:
            pass
    return pids


def steal_ticks() -> tuple[int, int]:
    """(steal, total) CPU ticks of the whole machine so far."""
    with open("/proc/stat") as stat:
        fields = [int(v) for v in stat.readline().split()[1:]]
    return fields[7], sum(fields)


class CpuMeter:
    """CPU time of the web process, the loop process and Chromium over a window."""

    def __init__(self, web_pid: int, loop_pid: int) -> None:
        self.groups = {"web": [web_pid], "loop": [loop_pid], "chromium": chromium_pids()}
        self.t0, self.ticks0, self.steal0 = time.monotonic(), self._ticks(), steal_ticks()

    def _ticks(self) -> dict[str, int]:
        return {g: sum(cpu_ticks(p) for p in pids) for g, pids in self.groups.items()}

    def shares(self) -> dict[str, float]:
        """Each group's CPU over the window as a share of one core, the host's steal, and the
load average (1 min) as the row ended: the machine is shared, compare ratios only."""
        wall = time.monotonic() - self.t0
        now, steal = self._ticks(), steal_ticks()
        out = {g: (now[g] - self.ticks0[g]) / TICK_S / wall for g in now}
        out["steal"] = (steal[0] - self.steal0[0]) / max(1, steal[1] - self.steal0[1])
        return out


# --- one tree ---------------------------------------------------------------------------


def forecast_shown(page, timeout_s: float = 300.0) -> None:
    """Until the page has its fidelity forecast of the scenario it shows (computed in the
    web process when the page loads or its scenario changes: seconds of CPU the first
    time a setting is seen, then kept), so that it does not fall into a window."""
    page.wait_for_function(
        "() => !document.getElementById('fidelity').textContent.includes('computing')",
        timeout=timeout_s * 1000)


def _loop(api: httpx.Client) -> tuple[dict, dict]:
    state = api.get("/api/state").json()
    return state, state["loop"]


def free_floating(api: httpx.Client, page, web_pid: int, warmup_s: float,
                  window_s: float) -> dict:
    """The hand-driven scenario: its cycle over ``window_s`` after ``warmup_s``."""
    body = {"loop": {"duration_s": warmup_s + window_s + 30.0}}
    state = api.post("/api/scenarios/free-floating/start", json=body, timeout=120).json()
    if state.get("status") != "running":
        raise RuntimeError(f"free-floating did not start: {state}")
    t_start = time.monotonic()
    page.wait_for_timeout(1000)  # the page's poll (every 0.5 s) sees the new run
    forecast_shown(page)
    page.wait_for_timeout(max(0.0, t_start + warmup_s - time.monotonic()) * 1000)
    _, first = _loop(api)
    meter = CpuMeter(web_pid, first["pid"])
    p50s, p99s = [], []
    t0 = time.monotonic()
    n_windows = max(1, round(window_s / TIMING_WINDOW_S))
    for k in range(1, n_windows + 1):
        page.wait_for_timeout(max(0.0, t0 + k * window_s / n_windows - time.monotonic())
                              * 1000)
        state, loop = _loop(api)
        if state["status"] != "running":
            raise RuntimeError(f"free-floating ended early: {state['status']}: "
                               f"{state['reason']}")
        p50s.append(loop["cycle_time_us"]["p50"])
        p99s.append(loop["cycle_time_us"]["p99"])
    cpu = meter.shares()
    api.post("/api/stop")
    return {"p50": float(np.median(p50s)), "p99": float(np.median(p99s)),
            "misses": loop["deadline_misses"] - first["deadline_misses"],
            "cycles": loop["cycles"] - first["cycles"],
            "resyncs": loop["resyncs"] - first["resyncs"], "cpu": cpu,
            "window_s": time.monotonic() - t0}


def collision(api: httpx.Client, page, web_pid: int) -> dict:
    """The shipped collision run, whole: its final snapshot's cycle figures."""
    state = api.post("/api/scenarios/collision/start", json={}, timeout=180).json()
    if state.get("status") not in ("running", "finished"):
        raise RuntimeError(f"collision did not start: {state}")
    page.wait_for_timeout(1000)  # (the page's forecast of it was computed before)
    meter = CpuMeter(web_pid, state["loop"]["pid"])
    t0 = time.monotonic()
    deadline = t0 + 4 * state["duration_s"] + 60
    while state["status"] == "running" and time.monotonic() < deadline:
        page.wait_for_timeout(500)
        state = api.get("/api/state").json()
    cpu = meter.shares()
    loop = state["loop"]
    if state["status"] == "running":
        api.post("/api/stop")
    return {"p50": loop["cycle_time_us"]["p50"], "p99": loop["cycle_time_us"]["p99"],
            "misses": loop["deadline_misses"], "cycles": loop["cycles"],
            "resyncs": loop["resyncs"], "cpu": cpu, "window_s": time.monotonic() - t0,
            "status": state["status"]}


def measure_tree(tree: Path, cache_dir: str, warmup_s: float, window_s: float,
                 with_collision: bool) -> dict[str, dict]:
    """Both scenarios' figures for ``tree``, with the page and the viewer open."""
    from playwright.sync_api import sync_playwright

    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="web-loop-runs-") as runs_dir:
        proc, url = start_server(tree, runs_dir, cache_dir)
        try:
            with httpx.Client(base_url=url, timeout=60.0) as api, sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                try:
                    page = browser.new_page(viewport={"width": 1280, "height": 800})
                    page.goto(url + "/")
                    page.frame_locator("#viewer").locator("canvas").first.wait_for(
                        timeout=120_000)
                    page.wait_for_timeout(1000)
                    forecast_shown(page)  # the page's first scenario: collision
                    out["free-floating"] = free_floating(api, page, proc.pid, warmup_s,
                                                         window_s)
                    if with_collision:
                        out["collision"] = collision(api, page, proc.pid)
                finally:
                    browser.close()
        finally:
            stop_server(proc)
    return out


# --- the loop process's own costs (no server, no browser) ---------------------------------


def parts_child(scenario: str, seconds: float) -> dict:
    """In a fresh process of a tree: that tree's LoopCore (the loop process's body) runs
    ``scenario`` paced for ``seconds`` here, with its pipe and shared memory but no web
    process, and without the spin before each cycle (``spin_s`` 0), so that the process's
    CPU per period is the cycle plus what the loop does between cycles (polling the pipe,
    the heartbeat, a snapshot every 10 cycles, the pacing's bookkeeping and sleep)."""
    import multiprocessing
    from multiprocessing import shared_memory

    from app.backend import snapshots
    from app.backend.loop_process import LoopCore
    from app.backend.ring import RunTelemetry
    from app.scenarios import load_scenario

    base = load_scenario(scenario)
    config = base.model_copy(update={"loop": base.loop.model_copy(
        update={"duration_s": seconds})})
    shm = shared_memory.SharedMemory(create=True, size=snapshots.SHM_BYTES)
    ours, theirs = multiprocessing.Pipe()
    core = LoopCore(theirs, shm.name, config, scenario, "hil",
                    {"spin_s": 0.0, "rt_priority": 10, "nice": -10})
    ring = RunTelemetry(config, "hil")
    try:
        core.handle(("start", scenario, config, "hil", ring.name, None))
        cpu0 = time.process_time()
        core.run_paced()
        cpu_s = time.process_time() - cpu0
        n = min(core.cycle_count, len(core.cycle_ns))
        step_us = core.cycle_ns[:n] / 1e3
        cycles, cpu_per_cycle = core.cycle_count, 1e6 * cpu_s / core.cycle_count
        publish_us = []
        for _ in range(500):  # as the loop publishes: 10 cycles on (1 in 25 refreshes the
            core.cycle_count += core.snapshot_every  # percentiles: app/backend/loop_process.py)
            t0 = time.perf_counter_ns()
            core.publish()
            publish_us.append((time.perf_counter_ns() - t0) / 1e3)
        from app.sim.loop import Emulator

        tight = Emulator(config, mode="hil")  # the same run's steps back to back, unpaced
        tight.prepare()
        tight_us = []
        for _ in range(3000):
            t0 = time.perf_counter_ns()
            tight.step()
            tight_us.append((time.perf_counter_ns() - t0) / 1e3)
        return {"tight_p50": float(np.median(tight_us)),
                "tight_p99": float(np.percentile(tight_us, 99)),
                "status": core.status, "cycles": cycles,
                "misses": core.deadline_misses, "step_mean": float(step_us.mean()),
                "step_p50": float(np.median(step_us)),
                "step_p99": float(np.percentile(step_us, 99)),
                "cpu_per_cycle": cpu_per_cycle,
                "between": cpu_per_cycle - float(step_us.mean()),
                "publish": float(np.mean(publish_us)), "scheduling": core.scheduling}
    finally:
        ring.release()
        shm.close()
        shm.unlink()


def parts(trees: dict[str, Path], rounds: int, seconds: float) -> None:
    """parts_child of each tree in turn (free-floating and collision), ``rounds`` times."""
    import json

    print(f"\n## The loop process alone ({seconds:g} s paced, no spin, no web process)\n")
    print("| round | tree | scenario | step p50 / p99 / mean (µs) | the same back to back: "
          "p50 / p99 (µs) | CPU per period (µs) | between cycles (µs) | snapshot, mean (µs) | "
          "misses / cycles |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
    names = list(trees)
    numba = tempfile.TemporaryDirectory(prefix="web-loop-numba-")  # (nothing into the trees)
    for rnd in range(1, rounds + 1):
        for name in (names if rnd % 2 else names[::-1]):
            for scenario, secs in (("free-floating", seconds), ("collision", 8.0)):
                env = dict(os.environ, PYTHONPATH=str(trees[name]),
                           NUMBA_CACHE_DIR=os.path.join(numba.name, str(names.index(name))))
                out = subprocess.run(
                    [sys.executable, str(HERE), "--parts-child", scenario, str(secs)],
                    env=env, cwd=trees[name], capture_output=True, text=True, check=True)
                r = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"| {rnd} | {name} | {scenario} | {r['step_p50']:.0f} / "
                      f"{r['step_p99']:.0f} / {r['step_mean']:.0f} | "
                      f"{r['tight_p50']:.0f} / {r['tight_p99']:.0f} | "
                      f"{r['cpu_per_cycle']:.0f} | {r['between']:.0f} | {r['publish']:.0f} "
                      f"| {r['misses']} / {r['cycles']} |", flush=True)
    numba.cleanup()


# --- the table --------------------------------------------------------------------------


def row(rnd: int, name: str, scenario: str, r: dict) -> str:
    cpu = r["cpu"]
    if r.get("status", "finished") != "finished":  # e.g. a safety stop: its cycles so far
        scenario += f" ({r['status']})"
    return (f"| {rnd} | {name} | {scenario} | {r['p50']:.0f} | {r['p99']:.0f} | "
            f"{r['misses']} / {r['cycles']} | {r['resyncs']} | {r['window_s']:.0f} | "
            f"{cpu['loop']:.2f} / {cpu['web']:.2f} / {cpu['chromium']:.2f} | "
            f"{cpu['steal']:.1%} | {r['load']:.1f} |")


def summary(results: dict[str, dict[str, list[dict]]], names: list[str]) -> None:
    this, other = names
    print("\n| scenario | cycle p50 this / other (µs) | ratio | cycle p99 this / other (µs) "
          "| ratio | misses / cycles this | misses / cycles other |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for scenario in results[this]:
        a, b = results[this][scenario], results[other][scenario]
        p50a, p50b = (float(np.median([r["p50"] for r in x])) for x in (a, b))
        p99a, p99b = (float(np.median([r["p99"] for r in x])) for x in (a, b))
        ma, ca = sum(r["misses"] for r in a), sum(r["cycles"] for r in a)
        mb, cb = sum(r["misses"] for r in b), sum(r["cycles"] for r in b)
        print(f"| {scenario} | {p50a:.0f} / {p50b:.0f} | {p50a / p50b:.2f} | "
              f"{p99a:.0f} / {p99b:.0f} | {p99a / p99b:.2f} | {ma} / {ca} | {mb} / {cb} |")
    print("\n(p50, p99: medians over the rounds; misses and cycles: summed over them)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path,
                        help="another checkout of the project (e.g. git worktree add)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--warmup-s", type=float, default=10.0)
    parser.add_argument("--window-s", type=float, default=60.0)
    parser.add_argument("--no-collision", action="store_true")
    parser.add_argument("--parts", type=float, default=None, metavar="SECONDS",
                        help="instead: each tree's loop process alone (parts_child), "
                             "free-floating for SECONDS and the 8 s collision")
    parser.add_argument("--parts-child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.parts_child:
        import json

        print(json.dumps(parts_child(args.parts_child[0], float(args.parts_child[1]))))
        return
    if args.against is None:
        parser.error("--against TREE is needed")
    other = args.against.resolve()
    if not (other / "app" / "cli.py").exists():
        sys.exit(f"--against {other}: not a checkout of the project (no app/cli.py)")
    trees = {"this tree": ROOT, str(other): other}
    names = list(trees)
    if args.parts:
        print(f"load average {os.getloadavg()[0]:.2f} at the start")
        parts(trees, args.rounds, args.parts)
        print(f"load average {os.getloadavg()[0]:.2f} at the end")
        return
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
          f"{os.getloadavg()[2]:.2f} at the start; {os.cpu_count()} CPUs")
    print("\n| round | tree | scenario | cycle p50 (µs) | cycle p99 (µs) | deadline misses / "
          "cycles | resyncs | window (s) | CPU loop / web / Chromium (cores) | steal | load |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---|---:|---:|")
    results: dict[str, dict[str, list[dict]]] = {n: {} for n in names}
    with tempfile.TemporaryDirectory(prefix="web-loop-cache-") as cache:
        for rnd in range(1, args.rounds + 1):
            order = names if rnd % 2 else names[::-1]  # ABBA: a drift weighs on both
            for name in order:
                cache_dir = os.path.join(cache, str(names.index(name)))
                res = measure_tree(trees[name], cache_dir, args.warmup_s, args.window_s,
                                   not args.no_collision)
                for scenario, r in res.items():
                    r["load"] = os.getloadavg()[0]
                    results[name].setdefault(scenario, []).append(r)
                    print(row(rnd, name, scenario, r), flush=True)
    summary(results, names)
    print(f"\nload average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
          f"{os.getloadavg()[2]:.2f} at the end")


if __name__ == "__main__":
    main()
