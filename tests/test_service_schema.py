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

import numpy as np
import pytest
from service_server import ServiceProcess

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = os.environ.get("SCHEMATHESIS_EXAMPLES", "20")
CLI = shutil.which("schemathesis", path=str(Path(sys.executable).parent)) or shutil.which("schemathesis")


@pytest.mark.system
@pytest.mark.skipif(CLI is None, reason="schemathesis is not installed (pip install .[test])")
@pytest.mark.parametrize("token", [None, "s3cret"])
def test_schemathesis_finds_nothing(tmp_path, token):
    srv = ServiceProcess(tmp_path, queue_size=16, **({"token": token} if token else {}))
    try:
        env = {**os.environ, **_live_ids(srv.url, tmp_path, token)}
        cmd = [CLI, "--config-file", str(ROOT / "tests" / "schemathesis.toml"), "run", srv.url + "/openapi.json",
               "--checks", "all", "-n", EXAMPLES, "--generation-deterministic", "--request-timeout", "60"]
        if token:
            # With a token, the generated requests of the fuzzing and stateful phases: the coverage phase's
            # deterministic cases (half the run) are the tokenless run's, the token their only change.
            cmd += ["-H", f"Authorization: Bearer {token}", "--phases", "examples,fuzzing,stateful"]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
        assert r.returncode == 0, r.stdout[-6000:] + r.stderr[-2000:]
        assert " passed" in r.stdout and "failed" not in r.stdout.split("SUMMARY")[-1].lower()
        # Every route was reached with ids that exist (none answered only 404), and only the operations
        # whose bodies are files (bytes in the schema) mostly refused what was generated.
        assert "Missing test data" not in r.stdout, r.stdout[-6000:]
        assert _mismatched(r.stdout) <= FILE_BODIES, r.stdout[-6000:]
        assert srv.alive()
    finally:
        srv.stop()


FILE_BODIES = {"POST /environments", "POST /meshes", "POST /fabrics", "POST /scenes/{scene_id}/frames",
               "POST /scenes/{scene_id}/frames/batch", "POST /scenes/{scene_id}/frames/views"}


def _mismatched(report: str) -> set[str]:
    """The operations schemathesis lists under its "Schema validation mismatch" warning."""
    block = report.split("Schema validation mismatch:", 1)[1].split("\U0001f4a1", 1)[0] \
        if "Schema validation mismatch:" in report else ""
    return {line.strip()[2:] for line in block.splitlines() if line.strip().startswith("- ")}


def _live_ids(url: str, tmp_path: Path, token: str | None) -> dict[str, str]:
    """Ids the fuzzed routes take (tests/schemathesis.toml reads them from the environment): an
    environment, a mesh, a fabric and a scene for every operation, and a spare of each that a DELETE takes."""
    import httpx
    import trimesh
    from service_server import garment, scene_body, upload_environment
    from u3m_files import color, document, scalar, u3ma_bytes, visualisation

    from renderer.envmap import studio_environment, write_exr

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    octet = {**headers, "Content-Type": "application/octet-stream"}
    ids = {}
    with httpx.Client(base_url=url, timeout=120, headers=headers) as http:
        env = upload_environment(http, tmp_path)[0]["id"]
        # The spare: another map (an environment's id is its content's).
        write_exr(tmp_path / "spare.exr", studio_environment(64) * 0.5)
        spare_env = http.post("/environments", content=(tmp_path / "spare.exr").read_bytes(), headers=octet,
                              params={"name": "spare.exr", "lights": 6, "face_size": 16, "preset": "fast"})
        assert spare_env.status_code == 201, spare_env.text
        mesh = garment(16)
        obj = trimesh.Trimesh(mesh.positions, mesh.faces, process=False).export(file_type="obj").encode()
        meshes = []
        for _ in range(2):
            r = http.post("/meshes", content=obj + b"\n" * len(meshes), headers=octet, params={"format": "obj"})
            assert r.status_code == 201, r.text
            meshes.append(r.json()["id"])
        fabrics = []
        for grey in (0.3, 0.6):   # fabrics of constants alone: their ids are their bytes'
            fabric = document("1.1", visualisation("1.1", basecolor=color((grey, grey, grey)), roughness=scalar(0.8)))
            r = http.post("/fabrics", content=u3ma_bytes(fabric, {}), headers=octet)
            assert r.status_code == 201, r.text
            fabrics.append(r.json()["id"])
        scenes = []
        for _ in range(2):
            r = http.post("/scenes", json=scene_body(env, mesh))
            assert r.status_code == 201, r.text
            scenes.append(r.json()["id"])
        # A frame, so that the scene's latest image exists.
        r = http.post(f"/scenes/{scenes[0]}/frames", content=np.asarray(mesh.positions, "<f4").tobytes(), headers=octet)
        assert r.status_code == 200, r.text
    ids.update(GR_FUZZ_ENV=env, GR_FUZZ_ENV_SPARE=spare_env.json()["id"], GR_FUZZ_MESH=meshes[0],
               GR_FUZZ_MESH_SPARE=meshes[1], GR_FUZZ_FABRIC=fabrics[0], GR_FUZZ_FABRIC_SPARE=fabrics[1],
               GR_FUZZ_SCENE=scenes[0], GR_FUZZ_SCENE_SPARE=scenes[1])
    assert len(set(ids.values())) == 8
    return ids
