"""The manual, offered offline at /manual/.

``mkdocs build`` (scripts/serve builds it when stale, scripts/test with ``--strict``) writes
the manual to site/ at the top of the source tree; this serves that folder as it is. Its
pages fetch nothing from elsewhere (mkdocs.yml: no web fonts, maths by a local KaTeX, the
search index local), so a lab without internet reads it whole. Where it was not built
(e.g. an installed package without the sources), /manual/ says how to build it.
"""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

MANUAL_PATH = "/manual"
NOT_BUILT = ("<h1>The manual is not built</h1><p>In the source tree, <code>bash scripts/serve"
             "</code> builds it before it starts the server (or <code>.venv/bin/mkdocs build"
             "</code>), then reload this page.</p>")


def manual_dir() -> Path | None:
    """The built manual: $ORBIT_EMULATOR_MANUAL, else site/ of the source tree; None when
    neither holds an index.html."""
    candidates = []
    if os.environ.get("ORBIT_EMULATOR_MANUAL"):
        candidates.append(Path(os.environ["ORBIT_EMULATOR_MANUAL"]))
    candidates.append(Path(__file__).resolve().parents[2] / "site")
    for path in candidates:
        if (path / "index.html").is_file():
            return path
    return None


def install(app: FastAPI) -> None:
    """GET /manual/… from the built manual (found now, when the app is made), or a page
    saying how to build it (404)."""
    root = manual_dir()

    @app.get(MANUAL_PATH, include_in_schema=False)
    async def manual_slash():
        return RedirectResponse(f"{MANUAL_PATH}/")

    if root is None:
        @app.get(MANUAL_PATH + "/{rest:path}", include_in_schema=False)
        async def not_built(rest: str):
            return HTMLResponse(NOT_BUILT, status_code=404)
        return
    app.mount(MANUAL_PATH, StaticFiles(directory=root, html=True), name="manual")
