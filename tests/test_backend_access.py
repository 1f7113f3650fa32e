"""Access to the web app (app/backend/access.py, app/backend/viewer.py): a server beyond
loopback needs a token; with one, no request or websocket gets through without it, and
the 3D viewer is reachable only through the app."""

from __future__ import annotations

import asyncio
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import httpx
import pytest
import viser
import websockets

from app.backend.access import AccessError, access_token, is_loopback
from app.backend.server import create_app
from tests.live_server import LiveServer

TOKEN = "t0ken-for-the-access-tests-0123456789"
EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"
SUBPROTOCOL = [f"viser-v{viser.__version__}"]


@pytest.fixture(scope="module")
def live():
    with LiveServer(token=TOKEN) as server:
        yield server


def test_loopback_is_told_from_what_others_can_reach():
    assert all(map(is_loopback, ["127.0.0.1", "127.1.2.3", "::1", "[::1]", "localhost"]))
    assert not any(map(is_loopback, ["0.0.0.0", "::", "192.168.1.10", "lab-pc.local"]))


def test_a_bind_beyond_loopback_without_a_token_is_refused(monkeypatch):
    monkeypatch.delenv("ORBIT_EMULATOR_TOKEN", raising=False)
    with pytest.raises(AccessError, match=r"--host 0.0.0.0: not a loopback address, so "
                                          r"anyone who can reach it could drive the arms"):
        access_token("0.0.0.0")
    with pytest.raises(AccessError, match="a token is required"):
        create_app(host="0.0.0.0")
    token, generated = access_token("0.0.0.0", generate=True)
    assert generated and len(token) >= 32
    assert access_token("127.0.0.1") == (None, False)
    monkeypatch.setenv("ORBIT_EMULATOR_TOKEN", "short")
    with pytest.raises(AccessError, match="ORBIT_EMULATOR_TOKEN: at least 16 characters"):
        access_token("0.0.0.0")
    for unsafe in ("q1+Zt/9kLm3xYw2Pa8Bc", "abcdefghijklmnop;x=1", "abcdefghijklmnop q"):
        monkeypatch.setenv("ORBIT_EMULATOR_TOKEN", unsafe)  # would not survive URL/cookie
        with pytest.raises(AccessError, match=r"only letters, digits and \. _ ~ -"):
            access_token("0.0.0.0")


def test_requests_without_the_token_get_401_and_change_nothing(live):
    before = live.state()
    for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"},
                    {"Authorization": f"Basic {TOKEN}"}, {"Cookie": "orbit_emulator_token=x"}):
        for method, path in (("GET", "/api/health"), ("GET", "/api/state"),
                             ("GET", "/api/metrics"), ("GET", "/api/telemetry"),
                             ("POST", "/api/scenarios/collision/start"), ("POST", "/api/stop"),
                             ("GET", "/"), ("GET", "/viewer/"), ("GET", "/docs")):
            r = httpx.request(method, live.url + path, headers=headers,
                              json={} if method == "POST" else None)
            assert r.status_code == 401, (method, path, headers, r.status_code)
            assert r.headers["www-authenticate"] == "Bearer"
            assert r.json()["detail"].startswith("a token is required")
    after = live.state()
    assert after["status"] == before["status"] == "idle"
    assert after["generation"] == before["generation"]


def test_the_printed_link_sets_a_cookie_that_opens_the_page_the_api_and_the_viewer(live):
    with httpx.Client(base_url=live.url) as browser:
        page = browser.get(f"/?token={TOKEN}")
        assert page.status_code == 200 and 'id="start-button"' in page.text
        cookie = page.headers["set-cookie"]
        assert cookie.startswith(f"orbit_emulator_token={TOKEN};")
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        assert browser.get("/api/health").json()["viewer"] == "/viewer/"  # the cookie alone
        assert browser.get("/viewer/").status_code == 200


def test_no_page_of_another_origin_may_frame_the_app(live):
    """Every answer (the page, the viewer, the API, a kept run's replay, a refusal) says
    that only the app's own pages may frame it: X-Frame-Options and CSP frame-ancestors
    (the browser test shows a page on another port failing to frame it)."""
    auth = {"Authorization": f"Bearer {TOKEN}"}
    for path, headers in (("/", auth), ("/viewer/", auth), ("/api/state", auth),
                          ("/api/replay.html", auth), ("/api/state", {})):
        r = httpx.get(live.url + path, headers=headers)
        assert r.headers["x-frame-options"] == "SAMEORIGIN", (path, r.status_code)
        assert r.headers["content-security-policy"] == "frame-ancestors 'self'", path


def test_a_browser_opening_the_link_is_sent_on_without_the_token_in_its_url(live):
    r = httpx.get(f"{live.url}/?token={TOKEN}&x=1", headers={"Accept": "text/html"})
    assert r.status_code == 303 and r.headers["location"] == "/?x=1"
    assert r.headers["set-cookie"].startswith(f"orbit_emulator_token={TOKEN};")


def test_other_cookies_do_not_hide_the_token_cookie(live):
    for cookie in ("theme=dark mode; orbit_emulator_token=" + TOKEN,
                   'x={"a":1}; orbit_emulator_token=' + TOKEN,
                   "t=a\\b; orbit_emulator_token=" + TOKEN):
        r = httpx.get(live.url + "/api/health", headers={"Cookie": cookie})
        assert r.status_code == 200, cookie


def test_odd_viewer_paths_get_an_answer_not_a_server_error(live):
    for path in ("/viewer/a%20b", "/viewer/%00", "/viewer/..%2f..%2fetc/passwd"):
        r = live.client.get(path)
        assert r.status_code < 500 or r.status_code == 502, (path, r.status_code)
        assert r.status_code != 500


def test_the_access_log_never_shows_the_token():
    import logging

    from app.backend.cli import RedactToken

    record = logging.LogRecord("uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
                               ("127.0.0.1:5", "GET", f"/?x=1&token={TOKEN}&y=2", "1.1", 303),
                               None)
    assert RedactToken().filter(record)
    assert TOKEN not in record.getMessage() and "token=<token>&y=2" in record.getMessage()


def _viewer_frames(url: str, **kwargs) -> int:
    """Connect to the viewer websocket; the number of frames the scene sends in 2 s."""

    async def go() -> int:
        async with websockets.connect(url, subprotocols=SUBPROTOCOL, max_size=None,
                                      **kwargs) as ws:
            frames = 0
            try:
                async with asyncio.timeout(2.0):
                    async for _ in ws:
                        frames += 1
            except TimeoutError:
                pass
            return frames

    return asyncio.run(go())


def test_the_viewer_websocket_needs_the_token(live):
    url = f"ws://127.0.0.1:{live.port}/viewer"
    with pytest.raises(websockets.InvalidStatus, match="HTTP 403"):
        _viewer_frames(url)
    with pytest.raises(websockets.InvalidStatus, match="HTTP 403"):
        _viewer_frames(url, additional_headers={"Cookie": "orbit_emulator_token=nope"})
    assert _viewer_frames(url, additional_headers={"Authorization": f"Bearer {TOKEN}"}) > 0
    assert _viewer_frames(url, additional_headers={
        "Cookie": f"orbit_emulator_token={TOKEN}"}) > 0
    # a page on another site carries the cookie but names its origin: refused
    with pytest.raises(websockets.InvalidStatus, match="HTTP 403"):
        _viewer_frames(url, additional_headers={"Cookie": f"orbit_emulator_token={TOKEN}",
                                                "Origin": "http://evil.example"})


def test_viser_itself_answers_no_one_but_the_app(live):
    """viser listens on loopback only, and refuses every request without the app's
    secret: the page, and the websocket a page from any site could open to it."""
    direct = f"127.0.0.1:{live.viser_port}"
    assert httpx.get(f"http://{direct}/").status_code == 403
    with pytest.raises(websockets.InvalidStatus, match="HTTP 403"):
        _viewer_frames(f"ws://{direct}/")


def _serve(env: dict, *args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([EXE, "serve", "--port", "0", *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, deadline = "", time.monotonic() + 120
    while "3D viewer" not in out:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                raise AssertionError(proc.stderr.read())
        out += line
        assert time.monotonic() < deadline, out
    return proc, out


def test_serve_prints_the_real_port_and_the_token_link_and_stops_cleanly_on_ctrl_c(tmp_path):
    env = {**os.environ, "ORBIT_EMULATOR_TOKEN": TOKEN}
    proc, out = _serve(env, "--token-file", str(tmp_path / "token"))
    try:
        port = int(re.search(r"web app\s+http://127\.0\.0\.1:(\d+)/", out).group(1))
        assert port > 0
        assert f"http://127.0.0.1:{port}/viewer/?token=$ORBIT_EMULATOR_TOKEN" in out
        assert TOKEN not in out  # a token given is not printed
        assert (tmp_path / "token").read_text() == TOKEN + "\n"
        assert oct((tmp_path / "token").stat().st_mode & 0o777) == "0o600"
        url = f"http://127.0.0.1:{port}/api/health"
        assert httpx.get(url).status_code == 401
        assert httpx.get(url, headers={"Authorization": f"Bearer {TOKEN}"}).status_code == 200
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err  # the shell's code for Ctrl+C, after a clean stop
    assert "Application shutdown complete" in err and "Traceback" not in err


def test_the_token_file_is_never_written_through_a_link_nor_left_readable(tmp_path):
    from app.backend.cli import _write_secret

    old = tmp_path / "old"
    old.write_text("x")
    old.chmod(0o644)
    _write_secret(old, TOKEN)
    assert old.read_text() == TOKEN + "\n" and oct(old.stat().st_mode & 0o777) == "0o600"
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "link").symlink_to(victim)
    with pytest.raises(ValueError, match="--token-file: cannot write"):
        _write_secret(tmp_path / "link", TOKEN)
    assert victim.read_text() == "precious"


@pytest.mark.parametrize(("env_token", "args", "message"), [
    (None, ["--host", "0.0.0.0"], "error: --host 0.0.0.0: not a loopback address"),
    ("short", ["--host", "0.0.0.0"], "error: ORBIT_EMULATOR_TOKEN: at least 16 characters"),
    (None, ["--token-file", "/tmp/x"], "error: --token-file: there is no token to write"),
])
def test_serve_refuses_an_open_bind_or_a_weak_token_before_binding(env_token, args, message):
    env = {k: v for k, v in os.environ.items() if k != "ORBIT_EMULATOR_TOKEN"}
    if env_token is not None:
        env["ORBIT_EMULATOR_TOKEN"] = env_token
    proc = subprocess.run([EXE, "serve", "--port", "0", *args], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_no_log_line_ever_shows_the_token(tmp_path):
    """A token session of a real `serve`: the link, then mis-cased and percent-encoded
    query tokens, on HTTP and on the viewer's websocket (whose lines go through uvicorn's
    error logger, not its access log). The whole log (stdout and stderr) holds the token
    nowhere, not even percent-encoded, and shows the lines with <token> in its place."""
    from urllib.parse import quote

    env = {**os.environ, "ORBIT_EMULATOR_TOKEN": TOKEN}
    proc, out = _serve(env)
    encoded = "".join(f"%{b:02X}" for b in TOKEN.encode())  # every byte percent-encoded
    try:
        port = int(re.search(r"web app\s+http://127\.0\.0\.1:(\d+)/", out).group(1))
        base = f"127.0.0.1:{port}"
        html = {"Accept": "text/html"}
        assert httpx.get(f"http://{base}/?token={TOKEN}", headers=html).status_code == 303
        for query in [f"token={TOKEN}", f"TOKEN={TOKEN}", f"Token={TOKEN}&x=1",
                      f"%74oken={TOKEN}", f"token={encoded}", f"x=1;token={TOKEN}",
                      f"other={TOKEN}", f"q={encoded}", f"q={encoded.lower()}",
                      f"q={TOKEN[:3]}{encoded[9:]}"]:  # under another name, (partly) encoded
            httpx.get(f"http://{base}/api/health?{query}")
            try:
                _viewer_frames(f"ws://{base}/viewer?{query}")
            except websockets.InvalidStatus:
                pass  # refused: the query's token is not one the server takes
        assert _viewer_frames(f"ws://{base}/viewer?token={TOKEN}") > 0
        assert quote(TOKEN) == TOKEN  # (what a client may send as is)
    finally:
        proc.send_signal(signal.SIGINT)
        rest, err = proc.communicate(timeout=60)
    log = out + rest + err
    assert "WebSocket /viewer?token=<token>" in log, log[-3000:]
    assert "WebSocket /viewer?TOKEN=<token>" in log and "/api/health?%74oken=<token>" in log
    assert TOKEN not in log and encoded not in log and encoded.lower() not in log
    assert encoded[9:] not in log and "/api/health?q=<token>" in log


def test_serve_on_a_port_in_use_says_so_before_starting_anything():
    """`serve --port P` with P taken: an `error:` line naming the port, exit 2, within
    seconds and before the loop process or the viewer started (their lines are absent)."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        t0 = time.monotonic()
        proc = subprocess.run([EXE, "serve", "--port", str(port)], capture_output=True,
                              text=True, timeout=60)
        took_s = time.monotonic() - t0
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert proc.stderr.startswith(f"error: --port {port}: cannot listen on 127.0.0.1 port "
                                  f"{port}: Address already in use"), proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert "startup" not in proc.stderr.lower() and "viser" not in proc.stderr.lower()
    print(f"\nport in use: refused after {took_s:.2f} s")
