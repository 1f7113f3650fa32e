"""Regenerate the manual's screenshots and figures (docs/img/), as the browser tests see
the app: a live server on free loopback ports, driven by Debian's headless Chromium
through Playwright, and a headless collision run.

    .venv/bin/python scripts/screenshots.py [--skip-page] [--skip-collision] [--sweep]

Writes docs/img/page.png (the control page with free-floating started), push.png (after a
10 N x 0.3 s push over REST, the live plots showing it), collision-forces.png and
collision-contact.png (the `collision` run's forces.png and contact_closeup.png, seed 0)
and fidelity_map.png (benchmarks/fidelity_map.png, which `python -m
benchmarks.contact_fidelity --map` draws). Takes about a minute. With --sweep, also
sweep-plot.png: benchmarks/sweeps/fidelity_map.toml run on Ray (27 runs, about 30 s on an
idle 2-core machine) and its restitution error drawn over the sponge's stiffness.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.browser import chromium  # noqa: E402
from tests.live_server import LiveServer  # noqa: E402

IMG = ROOT / "docs" / "img"
VIEWPORT = {"width": 1280, "height": 800}


def _hide_notices(page) -> None:
    """Hide the viewer's notice that WebGL runs in software (headless Chromium has no
    GPU): not what a reader's browser shows. Nothing else of the page is touched."""
    for frame in page.frames:
        if "/viewer/" in frame.url:
            frame.add_style_tag(content="#webgl-software-rendering {display: none !important}")
    page.wait_for_timeout(300)


def page_shots() -> None:
    """page.png and push.png from a live server and a real browser."""
    with LiveServer(default_scenario="free-floating") as live, chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(live.url + "/")
        live.wait_for_scene()
        started = live.client.post("/api/scenarios/free-floating/start",
                                   json={"loop": {"duration_s": 20.0}}).json()
        assert started["status"] == "running", started
        live.wait_for(lambda s: s["t_s"] >= 2.0, timeout_s=60.0)
        page.wait_for_timeout(1500)  # the viewer draws the scene
        _hide_notices(page)
        page.screenshot(path=str(IMG / "page.png"))
        print(f"page.png at t = {live.state()['t_s']:.2f} s")
        pushed = live.client.post("/api/push", json={
            "satellite": 1, "force_N": [0.0, 10.0, 0.0], "duration_s": 0.3})
        assert pushed.status_code == 200, pushed.text
        t_push = pushed.json()["t_s"]
        live.wait_for(lambda s: s["t_s"] >= t_push + 3.0, timeout_s=60.0)
        page.wait_for_timeout(1500)
        _hide_notices(page)
        page.screenshot(path=str(IMG / "push.png"))
        print(f"push.png at t = {live.state()['t_s']:.2f} s (pushed at {t_push:.2f} s)")
        live.client.post("/api/stop")


def collision_figures() -> None:
    """The collision's forces and contact close-up, from a headless run (seed 0)."""
    from app.runs.headless import run_scenario
    from app.scenarios import load_scenario

    with tempfile.TemporaryDirectory(prefix="orbit-emulator-shots-") as out:
        run_scenario(load_scenario("collision"), out_dir=out)
        shutil.copyfile(Path(out) / "forces.png", IMG / "collision-forces.png")
        shutil.copyfile(Path(out) / "contact_closeup.png", IMG / "collision-contact.png")


def sweep_plot() -> None:
    """The campaign tutorial's plot, from the real commands (the CLI, Ray included)."""
    import subprocess

    cli = [sys.executable, "-m", "app.cli"]
    with tempfile.TemporaryDirectory(prefix="orbit-emulator-sweep-") as out:
        subprocess.run([*cli, "sweep", str(ROOT / "benchmarks/sweeps/fidelity_map.toml"),
                        "--out", out, "--quiet"], check=True, cwd=ROOT)
        png = Path(out) / "plot.png"
        subprocess.run([*cli, "sweep-plot", out, "--x", "materials.sponge.stiffness_Npm",
                        "--metric", "collision.restitution_error", "--out", str(png)],
                       check=True, cwd=ROOT)
        shutil.copyfile(png, IMG / "sweep-plot.png")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-page", action="store_true", help="not the page's screenshots")
    parser.add_argument("--skip-collision", action="store_true",
                        help="not the collision's figures")
    parser.add_argument("--sweep", action="store_true",
                        help="also the campaign's plot (a 27-run sweep on Ray)")
    args = parser.parse_args(argv)
    IMG.mkdir(parents=True, exist_ok=True)
    if not args.skip_page:
        page_shots()
    if not args.skip_collision:
        collision_figures()
    if args.sweep:
        sweep_plot()
    shutil.copyfile(ROOT / "benchmarks" / "fidelity_map.png", IMG / "fidelity_map.png")
    for path in sorted(IMG.glob("*.png")):
        print(f"{path.relative_to(ROOT)}: {path.stat().st_size // 1024} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
