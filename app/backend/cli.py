"""The `orbit-emulator serve` subcommand: the web app (REST + static page + viser)."""

from __future__ import annotations

import argparse


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0..65535, got {value}")
    return value


def _cmd_serve(args: argparse.Namespace) -> int:
    import logging

    import uvicorn

    from app.backend.server import create_app
    from app.scenarios import scenario_names

    if args.scenario is not None and args.scenario not in scenario_names():
        raise ValueError(f"unknown scenario {args.scenario!r}; choose one of {scenario_names()}")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    app = create_app(viser_port=args.viser_port, host=args.host,
                     default_scenario=args.scenario)
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host

    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="info")
    server = uvicorn.Server(config)

    original_startup = server.startup

    async def startup(sockets=None):  # after the lifespan ran: the viser port is known
        await original_startup(sockets=sockets)
        viser_port = getattr(app.state, "viser_port", args.viser_port)
        port = args.port
        for srv in getattr(server, "servers", []):  # the port bound, also for --port 0
            for sock in srv.sockets:
                port = sock.getsockname()[1]
        print(
            f"\n  orbit-emulator web app   http://{shown}:{port}/\n"
            f"  REST API docs (OpenAPI)  http://{shown}:{port}/docs\n"
            f"  3D viewer (viser)        http://{shown}:{viser_port}/\n",
            flush=True,
        )

    server.startup = startup  # type: ignore[method-assign]
    server.run()
    return 0


def register_serve(subparsers) -> argparse.ArgumentParser:
    """Add `serve` to the `orbit-emulator` subcommands (an argparse subparsers object)."""
    p = subparsers.add_parser(
        "serve", help="run the web app: REST API, control page and 3D viewer",
        description="Run the web app: REST API (OpenAPI at /docs), the control page at / "
        "and the viser 3D viewer on its own port.",
    )
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1)")
    p.add_argument("--port", type=_port, default=8000, help="HTTP port (default 8000)")
    p.add_argument("--viser-port", type=_port, default=8080,
                   help="viser port (default 8080; the next free one if taken; 0: any)")
    p.add_argument("--scenario", default=None,
                   help="scenario shown at start-up (default: collision)")
    p.set_defaults(func=_cmd_serve)
    return p
