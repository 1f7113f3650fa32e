"""The `orbit-emulator` command line: the parser and the `propagate`, `run` and `scenarios`
subcommands; `serve` (the web app) is registered from :mod:`app.backend.cli`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from app.backend.cli import register_serve
from app.campaign.sweep import KEEP
from app.config import EmulatorConfig, assignment_override, load_config
from app.runs.run_config import resolve_run_config
from app.runs.store import DEFAULT_RUNS_DIR
from app.scenarios import scenario_descriptions, scenario_names


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number: {text!r}")
    return value


def _cmd_propagate(args: argparse.Namespace) -> int:
    from app.runs.propagate import propagate
    from app.runs.report import write_telemetry_csv

    config = load_config(args.config) if args.config else EmulatorConfig()
    steps = args.duration / args.dt
    if steps > MAX_PROPAGATE_STEPS:
        raise ValueError(f"--duration / --dt: {args.duration:g} s in steps of {args.dt:g} s is "
                         f"{steps:.3g} steps; at most {MAX_PROPAGATE_STEPS:,}")
    out = _output_dir(args.out)
    columns, rows = propagate(config, args.duration, args.dt)
    write_telemetry_csv(out / "telemetry.csv", columns, rows)
    _say(f"wrote {len(rows)} rows x {len(columns)} columns to {out / 'telemetry.csv'}")
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    scenarios = scenario_descriptions()
    width = max(map(len, scenarios), default=0)
    for name, desc in scenarios.items():
        _say(f"{name:{width}s}  {desc}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from app.runs.signals import interrupt_on_termination

    interrupt_on_termination()  # a scheduler's stop ends the run as Ctrl+C does: files written
    from tqdm import tqdm

    from app.runs.headless import RunFailed, headless_config, run_scenario
    from app.runs.replicate_pool import cores

    if args.bag_rate is not None and not args.bag:
        raise ValueError("--bag-rate: only with --bag")
    config = resolve_run_config(args.scenario, args.config, mode=args.mode,
                                duration_s=args.duration, seed=args.seed,
                                overrides=[assignment_override(a) for a in args.set])
    duration = config.loop.duration_s
    _check_output_dir(default_out(args), bag=args.bag)  # before the pre-flight, not after
    ideal = None
    if config.loop.mode == "hil":  # refused before anything is created or moves
        from app.runs.headless import checked_reference

        ideal = checked_reference(headless_config(config, duration), duration,
                                  processes=cores())  # the forecast's replicates
        if ideal and ideal.get("forecast"):  # the fidelity forecast, before the arms move
            from app.runs.report import forecast_text

            _say(forecast_text(ideal["forecast"]))
        from app.runs.metrics import noise_spin_warnings

        carried = [config.satellite_index(r.satellite) for r in config.robots]
        for text in noise_spin_warnings(config, carried):
            print(f"warning: {text}", file=sys.stderr)  # before the arms move
    out_dir = _output_dir(default_out(args))
    from app.runs.headless import check_run_files

    check_run_files(out_dir, bag=args.bag)  # before the run, not after it
    bar = tqdm(total=int(round(duration * config.loop.rate_hz)), unit="cycle",
               disable=args.quiet, file=sys.stderr)

    def progress(k, n):
        bar.update(k - bar.n)

    try:
        result = run_scenario(config, mode=config.loop.mode, duration_s=duration,
                              out_dir=out_dir, progress=progress, bag=args.bag,
                              bag_rate_hz=args.bag_rate, ideal=ideal, preflight_done=True,
                              plots_apart=cores() > 1,  # a core free
                              processes=cores())  # the interval's replicates
        bar.update(bar.total - bar.n)
    except RunFailed as failed:
        result = failed.result
    except KeyboardInterrupt:  # (run_scenario wrote what it had recorded first)
        bar.close()
        kept = [name for name in ("metrics.json", "telemetry.csv") if (out_dir / name).is_file()]
        print(f"interrupted: {', '.join(kept) or 'nothing'} written in {out_dir}",
              file=sys.stderr)
        return 130
    finally:
        bar.close()
    return _report_run(result)


def _report_run(result) -> int:
    """Print a headless run's summary, what it wrote and how it ended; its exit status."""
    from app.runs.report import run_summary

    metrics = result.metrics
    _say(run_summary(metrics))
    _say(f"\nwrote {', '.join(str(p) for p in result.files)}")
    written = [p for p in result.files if str(p).endswith("figures.json")]
    if written and not any(str(p).endswith(".png") for p in result.files):
        _say("no figure: nothing in this run moved beyond what a figure could show "
             "(docs/outputs.md)")
    if result.unwritten is not None:
        for problem in result.unwritten.problems:
            print(f"error: {problem}", file=sys.stderr)
        return EXIT_NOT_WRITTEN
    stop = metrics["safety_stop"]
    if stop:
        print(f"error: the run ended in a safety stop at t = {stop['t_s']:.3f} s (robot "
              f"{stop['robot']}: {stop['reason']}); everything up to it is written",
              file=sys.stderr)
        return EXIT_SAFETY_STOP
    if metrics["status"] == "error":
        print(f"error: the run failed at t = {metrics['duration_s']:.3f} s: "
              f"{metrics['error']}; everything up to it is written", file=sys.stderr)
        return EXIT_RUN_FAILED
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from app.runs.signals import interrupt_on_termination

    interrupt_on_termination()  # a scheduler's stop ends the sweep as Ctrl+C does
    from app.campaign.leftovers import adopt_orphans, end_leftovers
    from app.campaign.sweep import load_spec, plan_sweep
    from app.campaign.sweep_ray import describe, parse_address, run_sweep

    if args.address is not None:
        parse_address(args.address)
    plan = plan_sweep(load_spec(args.spec), Path(args.spec).parent, args.spec)
    out = _output_dir(args.out or f"sweeps/{Path(args.spec).stem}")
    kept = None if args.address else adopt_orphans()  # a local Ray's, ended with it
    try:
        summary = run_sweep(plan, out, address=args.address, workers=args.workers,
                            resume=args.resume, keep=args.keep, quiet=args.quiet)
    except KeyboardInterrupt:
        print(f"interrupted: {_sweep_left(plan, out)}", file=sys.stderr)
        return 130
    finally:
        if kept is not None:
            end_leftovers(kept)
    _say(describe(summary, out))
    failed = {s: summary["counts"].get(s, 0) for s in ("error", "lost")}
    if any(failed.values()):
        print(f"error: {failed['error']} run(s) ended in error and {failed['lost']} were lost "
              f"(of {summary['rows']}): their reasons are in {out / 'results.csv'}",
              file=sys.stderr)
        return EXIT_RUN_FAILED
    return 0


def _sweep_left(plan, out: Path) -> str:
    """What an interrupted sweep leaves: no table, a table of every run, or some rows."""
    from app.campaign.sweep import read_results

    table = out / "results.csv"
    if not table.is_file():
        return "no run had ended"
    _, rows = read_results(table)
    done = {r["run_id"] for r in rows if r["status"] != "lost"}
    if all(run.run_id in done for run in plan.runs()):  # stops at the first missing
        return f"every run had ended: {table} is whole"
    return f"the runs that ended are in {table} (--resume continues the sweep)"


def _cmd_sweep_plot(args: argparse.Namespace) -> int:
    from app.campaign.sweep_plot import plot_sweep

    path = plot_sweep(Path(args.dir), args.x, args.y, args.metric, args.out)
    _say(f"wrote {path}")
    return 0


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


EXIT_SAFETY_STOP = 3
"""`run`'s exit status when the run ended in a safety stop (2: the user's mistake)."""
EXIT_RUN_FAILED = 4
"""`run`'s exit status when the run raised once started (metrics.json: status "error");
`sweep`'s when any run of the table ended in error or was lost."""
EXIT_NOT_WRITTEN = 5
"""`run`'s exit status when some of its files could not be written where asked (each was
then written to a fresh folder of the temporary directory, named on stderr)."""


MAX_PROPAGATE_STEPS = 10_000_000
"""propagate keeps every step in memory (20 floats per satellite and step)."""


def _output_dir(path: str | Path) -> Path:
    """The output directory, created now: a path that cannot be one is the user's mistake,
    named before anything runs."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"--out: cannot create the directory {str(out)!r}: "
                         f"{err.strerror or err}") from None
    if not os.access(out, os.W_OK):
        raise ValueError(f"--out: the directory {str(out)!r} is not writable")
    return out


def _check_output_dir(path: str | Path, bag: bool = False) -> None:
    """What :func:`_output_dir` and the run files' check would refuse, found before the
    pre-flight (which may take seconds) without creating anything: a refused run leaves no
    folder behind."""
    from app.runs.headless import check_run_files

    out = Path(path)
    if out.is_dir():
        if not os.access(out, os.W_OK):
            raise ValueError(f"--out: the directory {str(out)!r} is not writable")
        check_run_files(out, bag=bag)
        return
    ancestor = next((p for p in out.absolute().parents if p.exists()), None)
    if out.exists() or ancestor is None or not os.access(ancestor, os.W_OK | os.X_OK):
        _output_dir(out)  # it cannot be created: its error, and nothing made


def default_out(args: argparse.Namespace) -> Path:
    return Path(args.out or f"runs/{args.scenario}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="orbit-emulator",
        description="Emulate on-orbit interactions with two UR10e arms (CW ODS + VFDM).",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "propagate", help="run the Orbital Dynamics Simulator alone",
        description="Propagate the satellites of a scenario file with the Orbital Dynamics "
                    "Simulator alone (no arms, no loop; its pulses applied) and write "
                    "OUT/telemetry.csv: one row per step, the satellites' columns of a run's "
                    f"telemetry. At most {MAX_PROPAGATE_STEPS:,} steps (--duration / --dt).")
    p.add_argument("--config", help="scenario TOML file (default: built-in defaults)")
    p.add_argument("--duration", type=_positive_float, default=600.0,
                   help="seconds of orbit time to propagate (default 600)")
    p.add_argument("--dt", type=_positive_float, default=0.002,
                   help="integration step in seconds (default 0.002)")
    p.add_argument("--out", default="out", help="output directory (default: out)")
    p.set_defaults(func=_cmd_propagate)

    p = sub.add_parser(
        "run", help="run a scenario headless: telemetry, metrics and plots",
        description="Run a scenario headless: telemetry, metrics and plots. Exit status: 0 "
                    "done, 2 a mistake in the command (nothing ran), 3 a safety stop, 4 the "
                    "run raised once started, 5 a file could not be written in --out "
                    "(written to a temporary folder instead, named on stderr); what was "
                    "recorded is written in every case.")
    p.add_argument("scenario", choices=scenario_names(), metavar="SCENARIO",
                   help=f"one of: {', '.join(scenario_names())}")
    p.add_argument("--mode", choices=("hil", "ideal"), default=None,
                   help="hil: arms in the loop (default); ideal: the reference without arms")
    p.add_argument("--duration", type=_positive_float, default=None,
                   help="seconds of scenario time")
    p.add_argument("--config", help="TOML file replacing the scenario's configuration")
    p.add_argument("--seed", type=int, default=None, help="seed of the sensor noise")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set passivity.enabled=false "
                        "or --set robots.1.q_home_rad=[0,-2,1.6,0.4,-1.57,0] (repeatable)")
    p.add_argument("--out", default=None, help="output directory (default: runs/SCENARIO)")
    p.add_argument("--bag", action="store_true",
                   help="also write the run as a ROS 2 bag (MCAP) in OUT/bag: joint states, "
                        "tf, F/T and ODS wrenches, satellite twists (Foxglove, PlotJuggler, "
                        "ros2 bag play)")
    p.add_argument("--bag-rate", type=_positive_float, default=None, metavar="HZ",
                   help="with --bag: at most HZ messages per topic and second of scenario "
                        "time (default: every cycle)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser(
        "sweep", help="run a campaign (parameter sweep, Monte Carlo) on Ray",
        description="Run a campaign (parameter sweep, Monte Carlo) on Ray. Exit status: 0 "
                    "every run of the table ran (ok, safety_stop or refused), 2 a mistake "
                    "in the spec or the command (nothing ran), 4 some runs ended in error "
                    "or were lost (counted on stderr; results.csv has their reasons), "
                    "130 interrupted.")
    p.add_argument("spec", metavar="SPEC.toml",
                   help="sweep spec: scenario, mode, [grid] and [random] settings, seeds or "
                        "draws, metrics (manual: A campaign on Ray)")
    p.add_argument("--out", default=None,
                   help="output directory: results.csv, summary.json, runs/ "
                        "(default: sweeps/SPEC)")
    p.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="join this Ray cluster's head (default: start Ray on this machine "
                        "for the sweep)")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="at most N runs at once (default: one per CPU Ray has)")
    p.add_argument("--resume", action="store_true",
                   help="continue the sweep in --out: runs already in results.csv are not "
                        "run again")
    p.add_argument("--keep", choices=KEEP, default="metrics",
                   help="what each run leaves in OUT/runs/RUN-ID: none, metrics "
                        "(metrics.json, default), telemetry (+ telemetry.csv), all (+ plots)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)

    p = sub.add_parser("sweep-plot", help="plot a metric of a sweep over one or two settings")
    p.add_argument("dir", metavar="DIR", help="a sweep's output directory (its results.csv)")
    p.add_argument("--x", required=True, metavar="KEY", help="the setting on the x axis")
    p.add_argument("--y", default=None, metavar="KEY",
                   help="a second setting: a heat map (mean over the other columns)")
    p.add_argument("--metric", required=True, metavar="NAME", help="a metric column")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="PNG to write (default: DIR/METRIC_vs_X[_Y].png)")
    p.set_defaults(func=_cmd_sweep_plot)

    p = sub.add_parser("scenarios", help="list the built-in scenarios")
    p.set_defaults(func=_cmd_scenarios)

    p = sub.add_parser(
        "runs", help="list the web app's runs kept on disk, or show one's summary",
        description="List the runs the web app wrote (serve --runs-dir), newest first: "
                    "id, mode, seed, simulated seconds, status and the restitution against "
                    "the ideal run; `runs show ID` prints one's summary and files.")
    p.add_argument("action", nargs="?", choices=("list", "show"), default="list",
                   help="list (default) or show")
    p.add_argument("id", nargs="?", metavar="ID", help="with show: the run's id")
    p.add_argument("--dir", default=str(DEFAULT_RUNS_DIR),
                   help=f"the runs directory (default {DEFAULT_RUNS_DIR}, as serve's)")
    p.set_defaults(func=_cmd_runs)

    register_serve(sub)
    return parser


def _cmd_runs(args: argparse.Namespace) -> int:
    """`runs`: the web app's runs kept on disk, newest first; `runs show ID`: one's
    summary (app/runs/store.py)."""
    from app.runs.store import RunStore

    store = RunStore(args.dir, create=False)
    if args.action == "show":
        if args.id is None:
            raise ValueError("runs show: which run? give its ID (`orbit-emulator runs` "
                             "lists them)")
        _say(run_text(store.run(args.id), store.folder(args.id)))
        return 0
    if args.id is not None:
        raise ValueError(f"runs: unexpected {args.id!r} (did you mean `runs show {args.id}`?)")
    records = store.runs()
    if not records:
        _say(f"no runs in {store.root}")
        return 0
    _say(f"{'ID':34s} {'MODE':5s} {'SEED':>4s} {'SIM S':>6s} {'STATUS':11s} "
         f"{'RESTITUTION':>11s} {'IDEAL':>6s} {'ERROR':>7s}")
    for r in records:
        h = r.get("headline") or {}
        _say(f"{r['id']:34s} {r.get('mode') or '-':5s} {_cell(r.get('seed'), 'd'):>4s} "
             f"{_cell(r.get('duration_s'), '.2f'):>6s} {r.get('status') or '-':11s} "
             f"{_cell(h.get('restitution'), '.3f'):>11s} "
             f"{_cell(h.get('restitution_ideal'), '.3f'):>6s} "
             f"{_cell(h.get('restitution_error'), '+.1%'):>7s}")
    return 0


def _cell(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def run_text(record: dict, folder: Path) -> str:
    """What `runs show` prints: the run's facts, its summary (as a headless run prints
    it) and its files."""
    from app.runs.report import run_summary

    lines = [f"run {record['id']}  ({folder})",
             f"scenario {record.get('scenario')}  mode {record.get('mode')}  seed "
             f"{record.get('seed')}  started {record.get('started_at')}  ended "
             f"{record.get('ended_at') or '-'}",
             f"status {record.get('status')}" + (f": {record['reason']}"
                                                  if record.get("reason") else "")]
    metrics = record.get("metrics")
    if metrics and "satellites" in metrics:
        lines += ["", run_summary(metrics)]
    elif record.get("status") in ("running", "starting"):
        lines += ["", "(still being recorded: its metrics come when it ends)"]
    else:
        lines += ["", "(no metrics: the run did not end on this server; its telemetry.csv "
                  "holds what it recorded)"]
    lines += ["", "files: " + ", ".join(record.get("files", []))]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """The command of ``argv`` (None: the process's arguments): its exit status."""
    return _dispatch(build_parser().parse_args(argv))


def program() -> None:
    """The `orbit-emulator` program (and ``python -m app.cli``): :func:`main` on the
    process's arguments, then the process ends with its status; after `run`, at once
    (:func:`_exit_at_once`)."""
    _open_standard_streams()
    args = build_parser().parse_args()
    try:
        status = _dispatch(args)
    except BrokenPipeError as err:  # printed elsewhere than by _say, to a reader gone
        _silence_stdout(err)
        status = 1
    if status == 0 and _stdout_lost and args.func in (_cmd_scenarios, _cmd_runs):
        status = 1  # a listing that could not be printed is a listing not given
    if args.func is _cmd_run:
        _exit_at_once(status)
    _flush_stdout()
    sys.exit(status)


class _StderrOrNothing:
    """``sys.stderr`` that goes silent once it cannot be written (a full disk, a reader
    gone): a progress bar or a warning that cannot be shown is no reason for a command
    to fail (``run 2>/dev/full`` ended before its run, exit 1)."""

    def __init__(self, stream) -> None:
        self._stream, self._lost = stream, False

    def write(self, text: str) -> int:
        if not self._lost:
            try:
                return self._stream.write(text)
            except OSError:
                self._lost = True
        return len(text)

    def flush(self) -> None:
        if not self._lost:
            try:
                self._stream.flush()
            except OSError:
                self._lost = True

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def _open_standard_streams() -> None:
    """A standard stream the caller closed (``run >&-``) opened on /dev/null instead: a
    command that writes to it then writes to nothing, where the closed descriptor made
    Python's stream None (an AttributeError in the first flush) and would have been
    the first file the run opened (its telemetry receiving what was printed)."""
    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        try:
            os.fstat(fd)
        except OSError:
            got = os.open(os.devnull, os.O_RDWR)
            if got != fd:
                os.dup2(got, fd)
                os.close(got)
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, "r" if fd == 0 else "w", closefd=False))  # noqa: SIM115
    sys.stderr = _StderrOrNothing(sys.stderr)


_stdout_lost = False
"""Whether something the command printed could not be written (:func:`_silence_stdout`)."""


def _silence_stdout(err: OSError) -> None:
    """What is left to print goes to /dev/null: stdout's reader went away (``run |
    head``), which is no fault of the command (its files are written), or stdout cannot
    be written (a full disk: said once on stderr)."""
    global _stdout_lost
    _stdout_lost = True
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    if not isinstance(err, BrokenPipeError):
        print(f"warning: stdout: {err.strerror or err}; the rest of the report is not "
              f"printed", file=sys.stderr)


def _flush_stdout() -> None:
    """stdout flushed; if it cannot be, silenced (not a traceback at exit)."""
    try:
        sys.stdout.flush()
    except OSError as err:
        _silence_stdout(err)


def _say(text: str) -> None:
    """``print(text)`` for a command's report: a stdout that cannot take it silences the
    rest (:func:`_silence_stdout`), and the command goes on (its status and its errors
    on stderr stay)."""
    try:
        print(text, flush=True)
    except OSError as err:
        _silence_stdout(err)


def _dispatch(args) -> int:
    """Run the parsed command: its exit status (2 for the user's mistake, 130 for Ctrl+C)."""
    try:
        return args.func(args)
    except (ValueError, LookupError) as err:  # ConfigError included: the user's mistake,
        print(f"error: {err}", file=sys.stderr)  # named; an unknown run too
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def _exit_at_once(status: int) -> None:
    """End the process with ``status`` now that everything is written, as the interpreter
    ends one up to its teardown: its threads' shutdown (it joins the threads left and
    runs their exit hooks: a process pool's, which stops the pool's workers, Ctrl+C or
    not), then the exit handlers (they end the processes the run started and flush the
    logs), the output flushed; but the teardown, which frees every object one by one
    (numba's kernels, the telemetry: a few tenths of a second of a run's wall time), is
    left to the system."""
    import atexit
    import logging
    import threading

    threading._shutdown()
    atexit._run_exitfuncs()
    logging.shutdown()
    _flush_stdout()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    program()
