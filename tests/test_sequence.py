import json

import numpy as np
import pytest
import trimesh
from conftest import asset

from renderer.cli import main
from renderer.errors import MeshError
from renderer.sequence import load_sequence, read_mdd, read_pc2, to_meshes, write_mdd, write_pc2


def _frames(n=4, v=10, seed=0):
    return np.random.default_rng(seed).random((n, v, 3)).astype(np.float32)


def test_pc2_and_mdd_round_trip(tmp_path):
    pos = _frames()
    write_pc2(tmp_path / "a.pc2", pos, start=1.0, rate=0.5)
    write_mdd(tmp_path / "a.mdd", pos, fps=24.0)
    a, b = read_pc2(tmp_path / "a.pc2"), read_mdd(tmp_path / "a.mdd")
    np.testing.assert_array_equal(a.positions, pos)
    np.testing.assert_array_equal(b.positions, pos)
    np.testing.assert_allclose(a.frame_times, [1.0, 1.5, 2.0, 2.5])
    np.testing.assert_allclose(b.frame_times, np.arange(4) / 24.0, rtol=1e-6)


@pytest.mark.parametrize("suffix", [".pc2", ".mdd"])
def test_truncated_point_caches_name_the_problem(tmp_path, suffix):
    path = tmp_path / f"a{suffix}"
    (write_pc2 if suffix == ".pc2" else write_mdd)(path, _frames())
    path.write_bytes(path.read_bytes()[:-7])
    with pytest.raises(MeshError, match="bytes"):
        load_sequence(path)


def test_garbage_and_nan_frames_are_rejected(tmp_path):
    (tmp_path / "x.pc2").write_bytes(b"hello world, not a cache at all")
    with pytest.raises(MeshError, match="POINTCACHE2"):
        load_sequence(tmp_path / "x.pc2")
    pos = _frames()
    pos[2, 3, 1] = np.nan
    write_pc2(tmp_path / "n.pc2", pos)
    with pytest.raises(MeshError, match="frame 2"):
        load_sequence(tmp_path / "n.pc2")
    with pytest.raises(MeshError, match="unknown sequence format"):
        load_sequence(tmp_path / "a.abc")


def test_point_cache_needs_a_matching_topology(tmp_path):
    sphere = trimesh.creation.icosphere(1)
    pos = np.stack([sphere.vertices * (1 + 0.1 * k) for k in range(3)]).astype(np.float32)
    write_pc2(tmp_path / "s.pc2", pos)
    seq = load_sequence(tmp_path / "s.pc2")
    with pytest.raises(MeshError, match="topology"):
        to_meshes(seq, None)
    from renderer.mesh import Mesh

    topo = Mesh.from_arrays(sphere.vertices, sphere.faces)
    mesh, frames = to_meshes(seq, topo)
    assert frames.shape == pos.shape and mesh.faces.shape == sphere.faces.shape
    wrong = Mesh.from_arrays(sphere.vertices[:-1], sphere.faces[:10])
    with pytest.raises(MeshError, match="vertices"):
        to_meshes(seq, wrong)


def test_obj_folder_sequence(tmp_path):
    sphere = trimesh.creation.icosphere(1)
    for k in range(3):
        trimesh.Trimesh(sphere.vertices * (1 + k), sphere.faces, process=False).export(tmp_path / f"f{k:03d}.obj")
    seq = load_sequence(tmp_path)
    assert seq.n_frames == 3
    np.testing.assert_allclose(seq.positions[2], sphere.vertices * 3, rtol=1e-6)


def test_shared_newton_simulation_reads_as_a_sequence():
    seq = load_sequence(asset("sim", "newton_shirt_drape_60f.npz"))
    assert seq.positions.shape == (61, 6436, 3) and seq.faces.shape == (12736, 3)


def test_sequence_command_renders_every_frame(tmp_path):
    sphere = trimesh.creation.icosphere(2, 0.3)
    trimesh.Trimesh(sphere.vertices, sphere.faces, process=False).export(tmp_path / "topo.obj")
    drop = np.stack([sphere.vertices + [0, 1.0 - 0.2 * k, 0] for k in range(4)]).astype(np.float32)
    write_pc2(tmp_path / "drop.pc2", drop)
    out = tmp_path / "frames"
    rc = main(["sequence", "--frames", str(tmp_path / "drop.pc2"), "--topology", str(tmp_path / "topo.obj"),
               "--out", str(out), "--size", "48x48", "--lights", "12", "--face-size", "32", "--shadow-size", "64"])
    assert rc == 0
    assert sorted(p.name for p in out.glob("frame_*.png")) == [f"frame_{k:04d}.png" for k in range(4)]
    assert (out / "preview.gif").stat().st_size > 0
    summary = json.loads((out / "timings.json").read_text())
    assert summary["frames"] == 4 and len(summary["per_frame"]) == 4
