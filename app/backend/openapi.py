"""The OpenAPI document as the server really answers (checked by schemathesis in
tests/test_backend_openapi.py).

FastAPI documents its own 422 shape and only the responses a route declares; this server
answers a 422 as :class:`Problem` (a message naming the field, and the errors), and every
operation may also meet the answers of the middlewares in app/backend/access.py (400 for a
foreign Host or a body that is not JSON, 403 for a foreign Origin, 413 and 415 for a body
too large or not JSON, 401 without the token where one is required) and, where it needs
the loop process, 503 while that is down.
"""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import BaseModel


class FieldError(BaseModel):
    loc: list[str | int]
    msg: str
    type: str


class Problem(BaseModel):
    """A 422: ``detail`` names the field and what is wrong; ``errors`` lists them one by
    one where the request failed validation (absent where the request was well formed but
    cannot be done, e.g. a start pose out of reach)."""

    detail: str
    errors: list[FieldError] | None = None


MESSAGE = {"$ref": "#/components/schemas/Message"}
ALWAYS = {
    "400": "the Host header names no allowed host, or the body could not be read",
    "403": "the Origin header names another site",
}
WITH_BODY = {
    "413": "the request body is over 64 KiB",
    "415": "the request body is not application/json",
}
LOOP_DOWN = "the loop process is dead or stalled: POST /api/reset or a start replaces it"
TOKEN = "the token is missing or wrong (Authorization: Bearer <token>, or the cookie)"


def install(app: FastAPI, token_required: bool) -> None:
    """Make ``app.openapi()`` build the document described above (once)."""

    def openapi() -> dict:
        if app.openapi_schema is None:
            app.openapi_schema = _document(app, token_required)
        return app.openapi_schema

    app.openapi = openapi


def _document(app: FastAPI, token_required: bool) -> dict:
    schema = get_openapi(title=app.title, version=app.version, description=app.description,
                         routes=app.routes)
    components = schema.setdefault("components", {})
    schemas = components.setdefault("schemas", {})
    problem = Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    schemas.update(problem.pop("$defs", {}))
    schemas["HTTPValidationError"] = problem  # FastAPI's 422s point here
    schemas.pop("ValidationError", None)
    schemas.setdefault("Message", {"type": "object", "required": ["detail"],
                                   "properties": {"detail": {"type": "string"}}})
    if token_required:
        components["securitySchemes"] = {"bearer": {"type": "http", "scheme": "bearer"}}
        schema["security"] = [{"bearer": []}]
    for path, operations in schema.get("paths", {}).items():
        for method, operation in operations.items():
            answers = dict(ALWAYS)
            if "requestBody" in operation or method in ("post", "put", "patch"):
                answers.update(WITH_BODY)
            if token_required:
                answers["401"] = TOKEN
            if path.startswith("/api/") and path != "/api/scenarios":
                answers["503"] = LOOP_DOWN
            responses = operation.setdefault("responses", {})
            for code, text in answers.items():
                responses.setdefault(code, {
                    "description": text,
                    "content": {"application/json": {"schema": MESSAGE}}})
            if "422" in responses:  # whoever raised it, a 422 is a Problem
                responses["422"]["content"] = {"application/json": {
                    "schema": {"$ref": "#/components/schemas/HTTPValidationError"}}}
    return schema
