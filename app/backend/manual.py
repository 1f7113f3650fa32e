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

from fastapi import FastAPI, Request
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
    """GET /manual/… from the built manual, looked for at each request (a manual built
    while the server runs is there at the next reload), or a page saying how to build it
    (404)."""
    served: dict[Path, StaticFiles] = {}

    @app.get(MANUAL_PATH, include_in_schema=False)
    async def manual_slash():
        return RedirectResponse(f"{MANUAL_PATH}/")

    @app.get(MANUAL_PATH + "/{rest:path}", include_in_schema=False)
    async def manual(rest: str, request: Request):
        root = manual_dir()
        if root is None:
            return HTMLResponse(NOT_BUILT, status_code=404)
        files = served.setdefault(root, StaticFiles(directory=root, html=True))
        return await files.get_response(rest, request.scope)
