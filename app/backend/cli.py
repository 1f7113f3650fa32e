"""The `orbit-emulator serve` subcommand: the web app (REST + static page + viser)."""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import socket
import tempfile
from pathlib import Path
from urllib.parse import unquote

from app.backend.access import TOKEN_ENV, access_token
from app.runs.store import DEFAULT_KEEP_RUNS, DEFAULT_RUNS_DIR


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0..65535, got {value}")
    return value


def _few_malloc_arenas(arenas: int = 2) -> None:
    """Let glibc keep at most ``arenas`` malloc arenas in the web process: its request
    threads each grew an arena of their own with the large, short-lived arrays of the
    heavy reads, and its memory crept up by tens of MB over a soak (benchmarks/soak.py).
    Nothing where the C library is not glibc."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-8, arenas)  # M_ARENA_MAX
    except (OSError, AttributeError):
        pass


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.backend.server import create_app
    from app.scenarios import scenario_names

    if args.scenario is not None and args.scenario not in scenario_names():
        raise ValueError(f"unknown scenario {args.scenario!r}; choose one of {scenario_names()}")
    token, generated = access_token(args.host, generate=args.generate_token)
    if args.token_file is not None:
        if token is None:
            raise ValueError("--token-file: there is no token to write (the server is on "
                             f"loopback and {TOKEN_ENV} is not set)")
        _write_secret(Path(args.token_file), token)
    _check_runs_dir(args.runs_dir)
    listener = bind_port(args.host, args.port)  # before the loop and the viewer start
    _few_malloc_arenas()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    app = create_app(viser_port=args.viser_port, host=args.host,
                     default_scenario=args.scenario, token=token, runs_dir=args.runs_dir,
                     keep_runs=args.keep_runs,
                     max_run_bytes=None if args.max_runs_mib is None
                     else int(args.max_runs_mib * 2**20))
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    if ":" in shown:
        shown = f"[{shown}]"
    link = ("" if token is None else
            f"?token={token}" if generated else f"?token=${TOKEN_ENV}")

    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="info")
    redact_logs(token)  # after uvicorn.Config, which sets up uvicorn's log handlers
    server = uvicorn.Server(config)

    original_startup = server.startup

    async def startup(sockets=None):  # after the lifespan ran: the viser port is known
        await original_startup(sockets=sockets)
        port = args.port
        for srv in getattr(server, "servers", []):  # the port bound, also for --port 0
            for sock in srv.sockets:
                port = sock.getsockname()[1]
        try:  # a stdout that cannot take it (a full disk, a reader gone) is no failure
            print(
                f"\n  orbit-emulator web app   http://{shown}:{port}/{link}\n"
                f"  REST API docs (OpenAPI)  http://{shown}:{port}/docs{link}\n"
                f"  3D viewer (viser)        http://{shown}:{port}/viewer/{link}\n"
                + ("" if token is None else
                   "  every request needs the token: the link sets a cookie; API clients "
                   "send Authorization: Bearer <token>\n"),
                flush=True,
            )
        except OSError as err:
            logging.getLogger("orbit_emulator.server").warning(
                "the app's addresses were not printed (stdout: %s); it serves at "
                "http://%s:%s/", err.strerror or err, shown, port)

    server.startup = startup  # type: ignore[method-assign]
    interrupted = []
    original_exit = server.handle_exit

    def handle_exit(sig, frame):  # uvicorn's handler, noting a Ctrl+C
        if sig == signal.SIGINT:
            interrupted.append(sig)
        original_exit(sig, frame)

    server.handle_exit = handle_exit  # type: ignore[method-assign]
    server.run(sockets=[listener])
    if interrupted:  # uvicorn re-raises it after the shutdown, but asyncio may drop that
        raise KeyboardInterrupt
    return 0


def _check_runs_dir(path: str) -> None:
    """--runs-dir made if missing and tried with a file written and removed: a folder the
    runs cannot be written to is named before the server starts (ValueError)."""
    root = Path(path)
    if root.exists() and not root.is_dir():
        raise ValueError(f"--runs-dir {path}: not a directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=root)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ValueError(f"--runs-dir {path}: the runs cannot be written there: "
                         f"{err.strerror or err}") from None


def bind_port(host: str, port: int) -> socket.socket:
    """A socket bound to (host, port) for uvicorn to listen on, or ValueError naming the
    port: checked before anything starts (a port in use used to start the loop and the
    viewer first, then end in uvicorn's message)."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0]
    except (socket.gaierror, UnicodeError) as err:
        raise ValueError(f"--host {host}: cannot be bound: {err}") from None
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
    except OSError as err:
        sock.close()
        raise ValueError(f"--port {port}: cannot listen on {host} port {port}: "
                         f"{err.strerror or err} (another server there? choose another "
                         f"--port, or 0 for any free one)") from None
    sock.set_inheritable(True)
    return sock


class RedactToken(logging.Filter):
    """Keeps the token out of every log line: the value of any URL query parameter named
    token in any case or percent-encoding (``?token=``, ``?TOKEN=``, ``?%74oken=``), and
    the token itself wherever it appears, any of its characters percent-encoded or not
    (``token``: the server's). Installed on the log
    handlers (:func:`redact_logs`), so that it sees every record, uvicorn's websocket lines
    (its error logger) and access lines alike."""

    def __init__(self, token: str | None = None) -> None:
        super().__init__()
        self.token = token
        self._encoded = None if not token else re.compile(
            "".join(f"(?:{re.escape(c)}|%{ord(c):02x})" for c in token), re.IGNORECASE)
        """The token with any of its characters percent-encoded (``%61b…``), anywhere."""

    def clean(self, text: str) -> str:
        text = QUERY_PARAM.sub(self._redact_param, text)
        return self._encoded.sub("<token>", text) if self._encoded else text

    @staticmethod
    def _redact_param(match: re.Match) -> str:
        name = unquote(match.group(2))
        return match.group(0) if name.strip().lower() != "token" else (
            f"{match.group(1)}{match.group(2)}=<token>")

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = self.clean(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(self.clean(a) if isinstance(a, str) else a
                                for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: self.clean(v) if isinstance(v, str) else v
                           for k, v in record.args.items()}
        if record.exc_text:
            record.exc_text = self.clean(record.exc_text)
        return True


QUERY_PARAM = re.compile(r"([?&;])([^=&;?#\s\"']*)=([^&;#\s\"']*)")
"""A URL query parameter: (separator, name, value)."""


def redact_logs(token: str | None) -> RedactToken:
    """:class:`RedactToken` on every handler of the root logger and of uvicorn's."""
    redact = RedactToken(token)
    for name in ("", "uvicorn", "uvicorn.error", "uvicorn.access", "websockets"):
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(redact)
    return redact


def _write_secret(path: Path, token: str) -> None:
    """The token into a file only its owner can read (for a health check in a container)."""
    try:  # not through a symbolic link, and 0600 even where the file was there before
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
        os.fchmod(fd, 0o600)
        with os.fdopen(fd, "w") as out:
            out.write(token + "\n")
    except OSError as err:
        raise ValueError(f"--token-file: cannot write {str(path)!r}: "
                         f"{err.strerror or err}") from None


def _at_least_one(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _positive_mib(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of MiB, got {text}")
    return value


def register_serve(subparsers) -> argparse.ArgumentParser:
    """Add `serve` to the `orbit-emulator` subcommands (an argparse subparsers object)."""
    p = subparsers.add_parser(
        "serve", help="run the web app: REST API, control page and 3D viewer",
        description="Run the web app: REST API (OpenAPI at /docs), the control page at / "
        "and the viser 3D viewer at /viewer/. Beyond loopback (--host 0.0.0.0) every "
        f"request needs a token: ${TOKEN_ENV}, or --generate-token.",
    )
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1)")
    p.add_argument("--port", type=_port, default=8000, help="HTTP port (default 8000)")
    p.add_argument("--viser-port", type=_port, default=0,
                   help="viser's own port on 127.0.0.1 (default: any free one); the viewer "
                        "is reached through the web app at /viewer/, never directly")
    p.add_argument("--generate-token", action="store_true",
                   help=f"on a bind beyond loopback without {TOKEN_ENV}: make a random token "
                        "and print the link that carries it")
    p.add_argument("--token-file", default=None,
                   help="also write the token to this file (mode 0600), e.g. for a container "
                        "health check")
    p.add_argument("--scenario", default=None,
                   help="scenario shown at start-up (default: collision)")
    p.add_argument("--runs-dir", default=str(DEFAULT_RUNS_DIR), metavar="DIR",
                   help="every run (page, panel or REST) is written here as it goes, one "
                        "folder per run, as a headless run's (default: "
                        f"{DEFAULT_RUNS_DIR}); list them with `orbit-emulator runs`")
    p.add_argument("--keep-runs", type=_at_least_one, default=DEFAULT_KEEP_RUNS, metavar="N",
                   help="keep the newest N runs in --runs-dir; older ones are deleted, "
                        f"oldest first (default {DEFAULT_KEEP_RUNS})")
    p.add_argument("--max-runs-mib", type=_positive_mib, default=None, metavar="MIB",
                   help="also keep the runs within this many MiB, deleting the oldest "
                        "first (default: no size cap)")
    p.set_defaults(func=_cmd_serve)
    return p
