"""USD stages as sequences (renderer/usd.py, usd-core): time-sampled points, transforms, up axis and
metres per unit from the stage, several meshes (the moving garment, the still body), bad stages, and
the shared newton simulation written to USD and rendered frame by frame through the command line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import asset
from pxr import Gf, Usd, UsdGeom, Vt

from renderer.errors import MeshError
from renderer.sequence import load_sequence, read_npz
from renderer.usd import read_usd

QUAD = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def _stage(path: Path, up="Y", mpu=1.0, tps=24.0):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetTimeCodesPerSecond(tps)
    return stage


def _mesh(stage, path: str, points_by_time: dict | np.ndarray, counts=(4,), indices=(0, 1, 2, 3)):
    m = UsdGeom.Mesh.Define(stage, path)
    m.GetFaceVertexCountsAttr().Set(Vt.IntArray(list(counts)))
    m.GetFaceVertexIndicesAttr().Set(Vt.IntArray(list(indices)))
    if isinstance(points_by_time, dict):
        for t, pts in points_by_time.items():
            m.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(pts, np.float32)), t)
    else:
        m.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(points_by_time, np.float32)))
    return m


def test_time_samples_become_frames_with_times_and_quads_become_two_triangles(tmp_path):
    path = tmp_path / "cloth.usda"
    stage = _stage(path, tps=30.0)
    _mesh(stage, "/World/cloth", {t: QUAD + [0.0, 0.1 * t, 0.0] for t in (1.0, 2.0, 3.0)})
    stage.GetRootLayer().Save()
    seq = load_sequence(path)
    assert seq.n_frames == 3 and seq.converted
    np.testing.assert_allclose(seq.frame_times, [1 / 30, 2 / 30, 3 / 30])
    np.testing.assert_allclose(seq.positions[2] - seq.positions[0], np.tile([0.0, 0.2, 0.0], (4, 1)), atol=1e-6)
    np.testing.assert_array_equal(np.sort(seq.faces, axis=1), [[0, 1, 2], [0, 2, 3]])


def test_z_up_centimetres_and_an_animated_transform_are_applied(tmp_path):
    """A Z-up stage in centimetres (metersPerUnit 0.01), the mesh under a parent translated over time:
    the frames come out Y up, in metres, moved by the transform."""
    path = tmp_path / "cm.usdc"
    stage = _stage(path, up="Z", mpu=0.01)
    xf = UsdGeom.Xform.Define(stage, "/World/rig")
    op = xf.AddTranslateOp()
    op.Set(Gf.Vec3d(0.0, 0.0, 0.0), 0.0)
    op.Set(Gf.Vec3d(0.0, 0.0, 100.0), 1.0)   # 100 cm up along Z
    _mesh(stage, "/World/rig/cloth", QUAD * 100.0)
    stage.GetRootLayer().Save()
    data = read_usd(path)
    assert data.up_axis == "Z" and data.meters_per_unit == pytest.approx(0.01)
    (m,) = data.meshes
    assert m.animated and m.positions.shape == (2, 4, 3)
    # Z up -> Y up, cm -> m: the transform's 100 cm along Z is 1 m along Y.
    np.testing.assert_allclose(m.positions[1] - m.positions[0], np.tile([0.0, 1.0, 0.0], (4, 1)), atol=1e-6)
    assert np.ptp(m.positions[0], axis=0).max() == pytest.approx(1.0)


def test_moving_meshes_are_the_sequence_and_still_ones_the_body(tmp_path):
    path = tmp_path / "scene.usda"
    stage = _stage(path)
    _mesh(stage, "/World/front", {0.0: QUAD, 1.0: QUAD + [0, 0, 0.1]})
    _mesh(stage, "/World/back", {0.0: QUAD + [0, 0, -1], 1.0: QUAD + [0, 0, -0.9]})
    # A triangle fan: a pentagon's 3 triangles.
    pent = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 6)[:5]]) + [3, 0, 0]
    _mesh(stage, "/World/body", pent, counts=(5,), indices=(0, 1, 2, 3, 4))
    stage.GetRootLayer().Save()
    seq = load_sequence(path)
    assert seq.positions.shape == (2, 8, 3) and len(seq.faces) == 4 and seq.faces.max() == 7
    (body,) = seq.extras
    assert body.name == "body" and body.faces.shape == (3, 3)


def test_a_named_garment_leaves_a_moving_body_its_own_frames(tmp_path):
    """Both meshes move (a simulated garment on an animated avatar): --garment names the garment's
    prims, and the body keeps its frames beside the sequence."""
    path = tmp_path / "avatar.usda"
    stage = _stage(path)
    _mesh(stage, "/World/Shirt_front", {0.0: QUAD, 1.0: QUAD + [0, 0, 0.1]})
    _mesh(stage, "/World/Avatar", {0.0: QUAD + [0, 0, -1], 1.0: QUAD + [0, 0.5, -1]})
    stage.GetRootLayer().Save()
    # By default both move, so both would be the garment.
    assert load_sequence(path).positions.shape == (2, 8, 3)
    seq = load_sequence(path, garment="/World/Shirt*")
    assert seq.positions.shape == (2, 4, 3) and [m.name for m in seq.extras] == ["Avatar"]
    (body,) = seq.extra_frames
    np.testing.assert_allclose(body[1] - body[0], np.tile([0.0, 0.5, 0.0], (4, 1)), atol=1e-6)
    assert load_sequence(path, garment="Avatar").extra_frames[0] is not None   # a name matches too
    with pytest.raises(MeshError, match="no mesh matches --garment 'Trousers'.*/World/Shirt_front, /World/Avatar"):
        load_sequence(path, garment="Trousers")
    out = tmp_path / "frames"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "sequence", "--frames", str(path), "--garment",
                        "/World/Shirt*", "--out", str(out), "--size", "32x32", "--preset", "fast"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(list(out.glob("frame_*.png"))) == 2


@pytest.mark.parametrize("make, message", [
    (lambda s: None, "has no mesh"),
    (lambda s: _mesh(s, "/World/still", QUAD), "no mesh of the file moves"),
    (lambda s: _mesh(s, "/World/bad", {0.0: QUAD, 1.0: QUAD}, counts=(4,), indices=(0, 1, 2, 9)), "outside the 4 points"),
    (lambda s: _mesh(s, "/World/grow", {0.0: QUAD, 1.0: np.vstack([QUAD, QUAD[:1]])}), "point count changes"),
    (lambda s: _mesh(s, "/World/nan", {0.0: QUAD, 1.0: QUAD * np.nan}), "NaN"),
])
def test_bad_stages_are_refused_with_what_is_wrong(tmp_path, make, message):
    path = tmp_path / "bad.usda"
    stage = _stage(path)
    make(stage)
    stage.GetRootLayer().Save()
    with pytest.raises(MeshError, match=message):
        load_sequence(path)


def test_a_file_that_is_not_usd_is_refused(tmp_path):
    path = tmp_path / "junk.usda"
    path.write_text("#usda 1.0\n(\n this is not usd\n")
    with pytest.raises(MeshError, match="not a USD stage"):
        load_sequence(path)
    with pytest.raises(MeshError, match="no such file"):
        load_sequence(tmp_path / "missing.usdc")


def _newton_usd(tmp_path: Path, frames: int) -> tuple[Path, np.ndarray]:
    """The shared newton simulation's first frames as a Z-up, centimetre USD stage, the way a USD
    writer stores a simulation: one mesh, one points sample per frame at 60 frames a second."""
    seq = read_npz(asset("sim", "newton_shirt_drape_60f.npz"))
    pos = seq.positions[:frames].astype(np.float64)          # Y up, metres
    path = tmp_path / "shirt.usdc"
    stage = _stage(path, up="Z", mpu=0.01, tps=60.0)
    z_up = np.stack([pos[..., 0], -pos[..., 2], pos[..., 1]], axis=-1) * 100.0   # the inverse of z_up_to_y_up, in cm
    m = _mesh(stage, "/World/shirt", {float(k): z_up[k] for k in range(frames)},
              counts=[3] * len(seq.faces), indices=seq.faces.reshape(-1).tolist())
    assert m
    stage.GetRootLayer().Save()
    return path, pos


def test_the_newton_simulation_through_usd_is_the_same_sequence(tmp_path):
    path, pos = _newton_usd(tmp_path, 4)
    seq = load_sequence(path)
    np.testing.assert_allclose(seq.positions, pos, atol=2e-5)
    np.testing.assert_array_equal(seq.faces, read_npz(asset("sim", "newton_shirt_drape_60f.npz")).faces)
    np.testing.assert_allclose(np.diff(seq.frame_times), 1 / 60)


def test_the_sequence_command_renders_a_usd_stage(tmp_path):
    path, _ = _newton_usd(tmp_path, 3)
    out = tmp_path / "frames"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "sequence", "--frames", str(path), "--out", str(out),
                        "--size", "48x48", "--preset", "fast"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert sorted(p.name for p in out.glob("frame_*.png")) == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]


def _stream(tmp_path, path, **kw):
    """A stage played through a real service by RenderClient.stream_usd (a small studio map, the fast
    preset): each frame's (scene id, index, answer), and the scene's details."""
    from service_server import ServiceProcess

    from garment_render_client import RenderClient
    from renderer.envmap.io import write_exr
    from renderer.envmap.procedural import studio_environment

    write_exr(tmp_path / "studio.exr", studio_environment(64))
    server = ServiceProcess(tmp_path)
    try:
        with RenderClient(server.url) as c:
            env = c.upload_environment(tmp_path / "studio.exr")
            got = list(c.stream_usd(path, env["id"], quality={"preset": "fast"}, **kw))
            return got, c._json("GET", f"/scenes/{got[0][0]}")
    finally:
        server.stop()


def test_the_client_streams_a_usd_stage_to_a_real_service(tmp_path):
    """A stage with a moving sphere (the garment, Z up, centimetres) and a still box (the body): the
    client registers both and plays every frame; the service answers each with its image."""
    import trimesh

    path = tmp_path / "drape.usda"
    stage = _stage(path, up="Z", mpu=0.01)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    v = np.asarray(ball.vertices)
    _mesh(stage, "/World/garment", {float(k): v + [0.0, 0.0, 5.0 * k] for k in range(3)},
          counts=[3] * len(ball.faces), indices=ball.faces.reshape(-1).tolist())
    box = trimesh.creation.box((30.0, 30.0, 10.0))
    _mesh(stage, "/World/body", np.asarray(box.vertices) - [0.0, 0.0, 30.0], counts=[3] * len(box.faces),
          indices=box.faces.reshape(-1).tolist())
    stage.GetRootLayer().Save()
    got, scene = _stream(tmp_path, path, output={"width": 48, "height": 48})
    assert [k for _, k, _ in got] == [0, 1, 2]
    assert all(f.frame_index == k and f.pil().size == (48, 48) for _, k, f in got)
    assert [(m["role"], m["n_vertices"]) for m in scene["meshes"]] == [("garment", 162), ("body", 8)]
    assert scene["frames_rendered"] == 3 and scene["up"] == "y"


def test_the_client_streams_a_moving_body_with_its_garment(tmp_path):
    """--garment's counterpart in the client: the body's own frames travel as body_positions, and the
    service's image follows them (the body moves out of the frame: its pixels go)."""
    import trimesh

    path = tmp_path / "avatar.usda"
    stage = _stage(path)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    faces = [3] * len(ball.faces), ball.faces.reshape(-1).tolist()
    _mesh(stage, "/World/Shirt", {0.0: np.asarray(ball.vertices), 1.0: np.asarray(ball.vertices) * 1.01}, *faces)
    body = np.asarray(ball.vertices) * 0.5 + [0.45, 0.0, 0.0]
    _mesh(stage, "/World/Avatar", {0.0: body, 1.0: body + [50.0, 0.0, 0.0]}, *faces)   # far out of view
    stage.GetRootLayer().Save()
    got, _ = _stream(tmp_path, path, garment="/World/Shirt", output={"width": 48, "height": 48, "background": "black"},
                     camera={"eye": [0.0, 0.0, 2.0], "target": [0.0, 0.0, 0.0]})
    first, second = (f.array() for _, _, f in got)
    right = (slice(None), slice(34, 48))   # where the body is at first
    assert first[right][..., 3].sum() > 0 and second[right][..., 3].sum() == 0
