"""The manual (mkdocs.yml, docs/, docs_src/reference.py, app/backend/manual.py): it builds
strictly, its generated reference covers every configuration key, CLI command and option,
REST path and metrics field, the README stays short, and the web app serves it at
/manual/ where its search works in a real browser.

One strict build for the module (~3 s) into a temporary folder; one live server.
"""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

from app.backend.server import create_app
from app.campaign.sweep import METRIC_FIELDS
from app.cli import build_parser
from app.config import EmulatorConfig
from tests.browser import HAVE_CHROMIUM, NEEDS_CHROMIUM, chromium

ROOT = Path(__file__).resolve().parent.parent
MKDOCS = Path(sys.executable).parent / "mkdocs"

pytestmark = pytest.mark.skipif(not MKDOCS.exists(), reason="needs mkdocs (the docs extra)")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run([str(MKDOCS), "build", "--strict", "--quiet", "-d", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr
    return out


def _text(site: Path, page: str) -> str:
    """A built page's text, tags removed and entities decoded."""
    raw = (site / page / "index.html").read_text()
    return html.unescape(re.sub(r"<[^>]+>", "", raw))


def _rows(site: Path, page: str) -> dict[str, str]:
    """A built page's table rows by their first cell's code: the rest of the row's text."""
    raw = (site / page / "index.html").read_text()
    rows = {}
    for row in re.findall(r"<tr>(.*?)</tr>", raw, re.S):
        first = re.match(r"\s*<td><code>(.*?)</code></td>(.*)", row, re.S)
        if first:
            rows[html.unescape(first.group(1))] = html.unescape(
                re.sub(r"<[^>]+>", " ", first.group(2)))
    return rows


def _meanings(site: Path, page: str) -> dict[str, list[str]]:
    """A built page's table rows by their first cell's code: each such row's last cell's text."""
    raw = (site / page / "index.html").read_text()
    cells = {}
    for row in re.findall(r"<tr>(.*?)</tr>", raw, re.S):
        tds = re.findall(r"<td>(.*?)</td>", row, re.S)
        first = re.match(r"\s*<code>(.*?)</code>\s*$", tds[0]) if tds else None
        if first:
            cells.setdefault(html.unescape(first.group(1)), []).append(
                html.unescape(re.sub(r"<[^>]+>", "", tds[-1])).strip())
    return cells


def _held(tp) -> tuple[str, type] | None:
    """(how its keys are written, model) of a field that holds a table: directly or
    optionally (``.``), as an array of tables (``.<i>.``), as a table of tables
    (``.<name>.``); None for a plain value."""
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return ".", tp
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is list:
        inner = _held(args[0])
        return (".<i>.", inner[1]) if inner else None
    if origin is dict:
        inner = _held(args[1])
        return (".<name>.", inner[1]) if inner else None
    for arg in args:  # an optional table
        inner = _held(arg)
        if inner:
            return inner
    return None


def _key_paths(model, prefix: str = "") -> list[str]:
    """The dotted path of every key of the configuration, as a scenario file nests it."""
    paths = []
    for name, field in model.model_fields.items():
        paths.append(prefix + name)
        held = _held(field.annotation)
        if held:
            paths += _key_paths(held[1], prefix + name + held[0])
    return paths


def test_the_strict_build_writes_every_section(site):
    for page in ("tutorials/first-push", "how-to/scenario-files", "reference/configuration",
                 "explanation/loop", "reference/api"):
        assert (site / page / "index.html").is_file(), page


def test_every_configuration_key_is_in_the_reference_with_its_docstring(site):
    rows = _rows(site, "reference/configuration")
    paths = _key_paths(EmulatorConfig)
    assert len(paths) > 150 and "satellites.<i>.gnc.waypoints.<i>.hold_s" in paths
    missing = [p for p in paths if p not in rows]
    assert not missing, missing
    # a key's docstring, type, default, unit and bounds reach its row
    row = " ".join(rows["vfdm.internal_dt_s"].split())
    assert "Virtual-model integration step" in row
    assert "float" in row and "0.02" in row and " s " in row and "> 0" in row
    # every key says what it is: a description of three words or more
    meanings = _meanings(site, "reference/configuration")
    short = [p for p in paths if len(meanings[p][0].split()) < 3]
    assert not short, short
    assert "N·m/rad" in rows["robots.<i>.rail.posture_stiffness_Nm_per_rad"]


def test_every_cli_command_and_option_is_in_the_reference(site):
    text = _text(site, "reference/cli")
    parser = build_parser()
    sub = next(a for a in parser._actions if hasattr(a, "choices") and isinstance(
        a.choices, dict))
    assert {"run", "sweep", "serve", "propagate", "scenarios"} <= set(sub.choices)
    for name, command in sub.choices.items():
        assert f"orbit-emulator {name}" in text, name
        for action in command._actions:
            for option in action.option_strings:
                assert option in text, f"{name} {option}"


def test_every_rest_path_is_in_the_reference(site):
    text = _text(site, "reference/rest")
    paths = create_app(runs_dir=None).openapi()["paths"]
    assert "/api/scenarios/{name}/start" in paths and "/api/push" in paths
    for path, ops in paths.items():
        for method in ops:
            assert f"{method.upper()} {path}" in text, (method, path)
    # every parameter (path, query) says what it takes
    meanings = _meanings(site, "reference/rest")
    for name in ("name", "run_id", "mode", "format", "a", "figure", "rate_hz"):
        assert all(len(m.split()) >= 2 for m in meanings[name]), (name, meanings[name])


def test_every_telemetry_column_is_in_the_reference_with_its_unit(site):
    """Those of two satellites and two arms on rails: each column, its satellite or arm
    number written {i} or {k}, has a row with the unit its suffix states and a meaning."""
    from app.sim.telemetry import loop_columns

    rows = _meanings(site, "reference/telemetry")
    units = _rows(site, "reference/telemetry")
    columns = {re.sub(r"^rob\d+_", "rob{k}_", re.sub(r"^sat\d+_", "sat{i}_", c))
               for c in loop_columns(2, 2, [1, 2])}
    assert "rob{k}_rail_s_m" in columns and len(columns) > 50
    missing = [c for c in columns if c not in rows or len(rows[c][0].split()) < 2]
    assert not missing, missing
    assert units["rob{k}_rail_v_mps"].split()[0] == "m/s"
    assert units["sat{i}_tx_Nm"].split()[0] == "N·m"


def test_every_metrics_field_is_in_the_reference_with_a_meaning(site):
    rows = _rows(site, "reference/metrics")
    for table, names in METRIC_FIELDS.items():
        for name in names:
            path = f"{table}.{name}" if table else name
            assert path in rows and len(rows[path].split()) >= 2, path


def test_the_manual_has_rendered_maths_and_fetches_nothing_from_elsewhere(site):
    page = (site / "explanation/equations/index.html").read_text()
    assert 'class="arithmatex"' in page
    for built in site.rglob("*.html"):
        tags = re.findall(r"<(?:script|link|img)\b[^>]*>", built.read_text())
        remote = [t for t in tags if re.search(r"(?:src|href)=\"(?:https?:)?//", t)
                  and "rel=\"canonical\"" not in t]
        assert not remote, (built, remote)


def test_the_readme_fits_on_two_screens():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 150, len(lines)
    text = "\n".join(lines)
    assert "bash scripts/serve" in text and "bash scripts/test" in text
    # its links into the manual lead somewhere (GitHub shows them; mkdocs does not check)
    targets = re.findall(r"\]\(((?!https?:)[^)#]+)", text)
    assert len(targets) > 20
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, missing


@pytest.mark.skipif(not HAVE_CHROMIUM, reason=NEEDS_CHROMIUM)
def test_serve_offers_the_manual_and_its_search_finds_restitution(site, monkeypatch,
                                                                  tmp_path):
    """The manual is looked for at each request: one built (here: pointed to) while the
    server runs is served at the next reload."""
    pytest.importorskip("playwright.sync_api")
    from tests.live_server import LiveServer

    (tmp_path / "index.html").write_text("<title>an older manual</title>")
    monkeypatch.setenv("ORBIT_EMULATOR_MANUAL", str(tmp_path))
    with LiveServer() as live, chromium() as browser:
        assert "an older manual" in live.client.get("/manual/").text
        monkeypatch.setenv("ORBIT_EMULATOR_MANUAL", str(site))
        page = browser.new_page(viewport={"width": 1200, "height": 800})
        page.goto(live.url + "/")
        href = page.get_attribute("#manual-link", "href")
        assert href == "/manual/"
        page.goto(live.url + href)
        assert "orbit-emulator manual" in page.title()
        page.click("input.md-search__input")  # typed as a reader does: the worker
        page.keyboard.type("restitution", delay=50)  # answers each keystroke
        results = page.locator(".md-search-result__item")
        results.first.wait_for(timeout=15_000)
        assert results.count() >= 3
        assert "restitution" in results.first.inner_text().lower()
