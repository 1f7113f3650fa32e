"""The `orbit-emulator` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.config import ConfigError, EmulatorConfig, load_config


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number: {text!r}")
    return value


def _cmd_propagate(args: argparse.Namespace) -> int:
    from app.propagate import propagate
    from app.report import write_telemetry_csv

    config = load_config(args.config) if args.config else EmulatorConfig()
    columns, rows = propagate(config, args.duration, args.dt)
    out = Path(args.out)
    write_telemetry_csv(out / "telemetry.csv", columns, rows)
    print(f"wrote {len(rows)} rows x {len(columns)} columns to {out / 'telemetry.csv'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="orbit-emulator",
        description="Emulate on-orbit interactions with two UR10e arms (CW ODS + VFDM).",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("propagate", help="run the Orbital Dynamics Simulator alone")
    p.add_argument("--config", help="scenario TOML file (default: built-in defaults)")
    p.add_argument("--duration", type=_positive_float, default=600.0, help="seconds")
    p.add_argument("--dt", type=_positive_float, default=0.002, help="step in seconds")
    p.add_argument("--out", default="out", help="output directory")
    p.set_defaults(func=_cmd_propagate)

    from app import commands  # run, scenarios, serve

    commands.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
