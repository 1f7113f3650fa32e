"""The API's interactive documentation (Swagger UI at /docs) from this server alone.

FastAPI's own /docs page loads Swagger UI's script and style sheet from a CDN, so a lab
without internet gets a blank page. Here the same page is served with the assets of the
installed ``swagger-ui-py`` package (Swagger UI 5, which reads OpenAPI 3.1) under
``/docs/assets/``, the favicon is the app's own, and the online spec validator is off
(Swagger UI would otherwise ask validator.swagger.io for a badge). ReDoc is not offered:
no installed package ships it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from fastapi import FastAPI, HTTPException
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse

DOCS_PATH = "/docs"
ASSETS_PATH = "/docs/assets"
ASSETS = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css"}
"""The only files the page needs, and the type each is served as."""


def assets_dir() -> Path:
    """static/ of the installed swagger-ui-py (found without importing the package, whose
    __init__ loads its web-framework handlers). RuntimeError if it is not installed."""
    spec = importlib.util.find_spec("swagger_ui")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("swagger-ui-py is not installed: pip install swagger-ui-py")
    path = Path(next(iter(spec.submodule_search_locations))) / "static"
    missing = [name for name in ASSETS if not (path / name).is_file()]
    if missing:
        raise RuntimeError(f"swagger-ui-py at {path} lacks {', '.join(missing)}")
    return path


def install(app: FastAPI) -> None:
    """GET /docs (the page) and GET /docs/assets/{name}; the app must have been made with
    docs_url=None and redoc_url=None (the CDN pages)."""
    root = assets_dir()

    @app.get(DOCS_PATH, include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} - API docs",
            swagger_js_url=f"{ASSETS_PATH}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS_PATH}/swagger-ui.css",
            swagger_favicon_url="/favicon.ico",
            swagger_ui_parameters={"validatorUrl": None},
        )

    @app.get(ASSETS_PATH + "/{name}", include_in_schema=False)
    async def asset(name: str) -> FileResponse:
        if name not in ASSETS:
            raise HTTPException(status_code=404, detail=f"no such asset: {name}")
        return FileResponse(root / name, media_type=ASSETS[name])
