"""glTF / GLB morph-target animation as a sequence (renderer/gltf_morph.py, pygltflib): a GLB written
here with two position targets animated over three keyframes, a node transform, a still mesh beside
it, sparse and cubic-spline samplers, and bad files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pygltflib as g
import pytest

from renderer.errors import MeshError
from renderer.sequence import load_sequence

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
FACES = np.array([0, 1, 2, 0, 2, 3], np.uint16)
UP = np.tile([0.0, 0.0, 1.0], (4, 1)).astype(np.float32)          # target 0: +z
WIDE = (QUAD * [1.0, 0.0, 0.0]).astype(np.float32)                  # target 1: x doubled
TIMES = np.array([0.0, 0.5, 1.0], np.float32)
WEIGHTS = np.array([[0, 0], [1, 0], [0.5, 1]], np.float32)          # per keyframe, per target


class _Writer:
    def __init__(self):
        self.blob = bytearray()
        self.gltf = g.GLTF2(asset=g.Asset(version="2.0"))

    def accessor(self, array, kind, component=g.FLOAT, target=None, minmax=False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data),
                                                  target=target))
        self.blob.extend(data)
        flat = np.asarray(array, np.float64).reshape(len(array), -1)
        acc = g.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=component, count=len(array),
                         type=kind, max=flat.max(axis=0).tolist() if minmax else None,
                         min=flat.min(axis=0).tolist() if minmax else None)
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def save(self, path):
        self.gltf.buffers.append(g.Buffer(byteLength=len(self.blob)))
        self.gltf.set_binary_blob(bytes(self.blob))
        self.gltf.save(str(path))


def _file(tmp_path, interpolation="LINEAR", translation=(0.0, 2.0, 0.0), body=True, sparse=False):
    w = _Writer()
    pos = w.accessor(QUAD, "VEC3", minmax=True)
    idx = w.accessor(FACES, "SCALAR", g.UNSIGNED_SHORT)
    up = w.accessor(UP, "VEC3", minmax=True)
    if sparse:   # target 1 as a sparse accessor: zeros but for vertices 1 and 2
        vals = w.accessor(WIDE[[1, 2]], "VEC3")
        ids = w.accessor(np.array([1, 2], np.uint16), "SCALAR", g.UNSIGNED_SHORT)
        w.gltf.accessors.append(g.Accessor(componentType=g.FLOAT, count=4, type="VEC3", sparse=g.Sparse(
            count=2, indices=g.AccessorSparseIndices(bufferView=w.gltf.accessors[ids].bufferView, componentType=g.UNSIGNED_SHORT),
            values=g.AccessorSparseValues(bufferView=w.gltf.accessors[vals].bufferView))))
        wide = len(w.gltf.accessors) - 1
    else:
        wide = w.accessor(WIDE, "VEC3", minmax=True)
    prim = g.Primitive(attributes=g.Attributes(POSITION=pos), indices=idx, targets=[{"POSITION": up}, {"POSITION": wide}])
    w.gltf.meshes.append(g.Mesh(name="cloth", primitives=[prim], weights=[0.0, 0.0]))
    w.gltf.nodes.append(g.Node(mesh=0, translation=list(translation)))
    nodes = [0]
    if body:
        bpos = w.accessor((QUAD + [0, 0, -1]).astype(np.float32), "VEC3", minmax=True)
        w.gltf.meshes.append(g.Mesh(name="body", primitives=[g.Primitive(attributes=g.Attributes(POSITION=bpos),
                                                                          indices=idx)]))
        w.gltf.nodes.append(g.Node(mesh=1))
        nodes.append(1)
    w.gltf.scenes.append(g.Scene(nodes=nodes))
    times = w.accessor(TIMES[:, None], "SCALAR", minmax=True)
    if interpolation == "CUBICSPLINE":   # in-tangent, value, out-tangent per keyframe
        out = np.stack([np.zeros_like(WEIGHTS), WEIGHTS, np.zeros_like(WEIGHTS)], axis=1).reshape(-1, 1)
    else:
        out = WEIGHTS.reshape(-1, 1)
    weights = w.accessor(out.astype(np.float32), "SCALAR")
    w.gltf.animations.append(g.Animation(samplers=[g.AnimationSampler(input=times, output=weights,
                                                                      interpolation=interpolation)],
                                         channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(
                                             node=0, path="weights"))]))
    path = tmp_path / "cloth.glb"
    w.save(path)
    return path


def _expected(translation=(0.0, 2.0, 0.0)):
    return np.stack([QUAD + w[0] * UP + w[1] * WIDE + translation for w in WEIGHTS])


@pytest.mark.parametrize("interpolation", ["LINEAR", "STEP", "CUBICSPLINE"])
def test_the_weights_over_time_move_the_base_by_the_targets(tmp_path, interpolation):
    seq = load_sequence(_file(tmp_path, interpolation))
    assert seq.converted and seq.n_frames == 3
    np.testing.assert_allclose(seq.frame_times, TIMES)
    np.testing.assert_allclose(seq.positions, _expected(), atol=1e-6)
    np.testing.assert_array_equal(seq.faces, FACES.reshape(-1, 3))
    (body,) = seq.extras
    assert body.name == "body" and body.positions[:, 2].max() == pytest.approx(-1.0)


def test_a_sparse_target_is_read(tmp_path):
    seq = load_sequence(_file(tmp_path, sparse=True))
    np.testing.assert_allclose(seq.positions, _expected(), atol=1e-6)


def test_files_without_an_animation_or_not_gltf_are_refused(tmp_path):
    import trimesh

    still = tmp_path / "still.glb"
    trimesh.creation.box().export(still)
    with pytest.raises(MeshError, match="no mesh of the file moves .no morph-target animation"):
        load_sequence(still)
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"glTF\x02\x00\x00\x00junk")
    with pytest.raises(MeshError, match="not a glTF file"):
        load_sequence(junk)


def test_the_sequence_command_plays_a_glb(tmp_path):
    path = _file(tmp_path, translation=(0.0, 0.0, 0.0))
    out = tmp_path / "frames"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "sequence", "--frames", str(path), "--out", str(out),
                        "--size", "32x32", "--preset", "fast"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(list(out.glob("frame_*.png"))) == 3


def test_animated_node_transforms_move_a_mesh_and_make_it_the_garment(tmp_path):
    """A body walking: its node's translation and rotation animated (linear, a quarter turn about y
    over one second), no morph targets; the garment's weights keyed at other times. Every keyframe
    time is a frame, and each mesh is placed by its transform at that time."""
    w = _Writer()
    pos = w.accessor(QUAD, "VEC3", minmax=True)
    idx = w.accessor(FACES, "SCALAR", g.UNSIGNED_SHORT)
    w.gltf.meshes.append(g.Mesh(name="avatar", primitives=[g.Primitive(attributes=g.Attributes(POSITION=pos),
                                                                         indices=idx)]))
    w.gltf.nodes.append(g.Node(mesh=0))
    w.gltf.scenes.append(g.Scene(nodes=[0]))
    key_times = w.accessor(np.array([[0.0], [1.0]], np.float32), "SCALAR", minmax=True)
    moves = w.accessor(np.array([[0, 0, 0], [0, 0, 2]], np.float32), "VEC3")
    half = np.sqrt(0.5)
    turns = w.accessor(np.array([[0, 0, 0, 1], [0, half, 0, half]], np.float32), "VEC4")
    w.gltf.animations.append(g.Animation(
        samplers=[g.AnimationSampler(input=key_times, output=moves), g.AnimationSampler(input=key_times, output=turns)],
        channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="translation")),
                  g.AnimationChannel(sampler=1, target=g.AnimationChannelTarget(node=0, path="rotation"))]))
    path = tmp_path / "walk.glb"
    w.save(path)
    seq = load_sequence(path)
    assert seq.n_frames == 2 and not seq.extras   # it moves, so it is the sequence
    np.testing.assert_allclose(seq.positions[0], QUAD, atol=1e-6)
    # A quarter turn about y takes x to -z, then 2 along z.
    turned = np.stack([QUAD[:, 2], QUAD[:, 1], -QUAD[:, 0]], axis=1) + [0, 0, 2]
    np.testing.assert_allclose(seq.positions[1], turned, atol=1e-6)
    from renderer.gltf_morph import _sample

    mid = _sample(np.array([0.0, 1.0]), np.array([[0, 0, 0, 1.0], [0, half, 0, half]]), 0.5, "LINEAR", True)
    np.testing.assert_allclose(mid, [0, np.sin(np.pi / 8), 0, np.cos(np.pi / 8)], atol=1e-9)   # an eighth turn
