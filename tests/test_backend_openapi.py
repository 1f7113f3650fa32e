"""The OpenAPI document matches what the server answers: schemathesis generates requests
from it against the live app (the loop process included) and checks every answer: no 5xx,
every status code, content type, header and body as documented."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from tests.live_server import LiveServer

CHECKS = ("not_a_server_error,status_code_conformance,content_type_conformance,"
          "response_schema_conformance,response_headers_conformance")
ST = shutil.which("schemathesis") or f"{sys.prefix}/bin/schemathesis"


@pytest.mark.parametrize("token", [None, "the-schemathesis-token-0123456789"])
def test_schemathesis_finds_no_server_error_and_no_undocumented_answer(token, tmp_path):
    """25 examples per operation (bounded: about 400 requests, all to 127.0.0.1), every
    phase (examples, coverage incl. invalid inputs, fuzzing, stateful sequences). A
    request may take up to 120 s: a scenario's first forecast takes tens of seconds
    beside another test's run."""
    with LiveServer(token=token) as live:
        # with a token: also that every operation refuses a request without it
        auth = ["-H", f"Authorization: Bearer {token}"] if token else []
        checks = CHECKS + (",ignored_auth" if token else "")
        proc = subprocess.run(
            [ST, "run", f"{live.url}/openapi.json", *auth, "--checks", checks,
             "--max-examples", "25", "--seed", "7", "--request-timeout", "120",
             "--continue-on-failure", "--no-color"],
            capture_output=True, text=True, timeout=600, cwd=tmp_path)
        assert live.client.get("/api/health").status_code == 200  # and the loop lives on
        paths = live.client.get("/openapi.json").json()["paths"]
    operations = sum(len(methods) for methods in paths.values())
    assert operations >= 11
    assert proc.returncode == 0, proc.stdout[-8000:] + proc.stderr[-2000:]
    assert f"{operations}/{operations}" in proc.stdout  # every operation was tested
