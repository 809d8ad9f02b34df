"""schemathesis, every check and every phase, against the real service with and without a token:
the OpenAPI document is what the service does (error bodies, statuses, auth, the mesh_id-or-positions
rule, the registry's values), and no generated request gets a 5xx. A bounded budget (tests/schemathesis.toml
says which operations take files); run it longer with SCHEMATHESIS_EXAMPLES."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from service_server import ServiceProcess

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = os.environ.get("SCHEMATHESIS_EXAMPLES", "20")
CLI = shutil.which("schemathesis", path=str(Path(sys.executable).parent)) or shutil.which("schemathesis")


@pytest.mark.skipif(CLI is None, reason="schemathesis is not installed (pip install .[test])")
@pytest.mark.parametrize("token", [None, "s3cret"])
def test_schemathesis_finds_nothing(tmp_path, token):
    srv = ServiceProcess(tmp_path, queue_size=16, **({"token": token} if token else {}))
    try:
        cmd = [CLI, "--config-file", str(ROOT / "tests" / "schemathesis.toml"), "run", srv.url + "/openapi.json",
               "--checks", "all", "-n", EXAMPLES, "--generation-deterministic", "--request-timeout", "60"]
        if token:
            cmd += ["-H", f"Authorization: Bearer {token}"]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
        assert r.returncode == 0, r.stdout[-6000:] + r.stderr[-2000:]
        assert " passed" in r.stdout and "failed" not in r.stdout.split("SUMMARY")[-1].lower()
        assert srv.alive()
    finally:
        srv.stop()
