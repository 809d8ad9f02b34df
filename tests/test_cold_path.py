"""A one-shot command keeps what the next one reuses (renderer/user_cache.py): the PEM set with its
light decomposition, and the glossiness calibration's tables; the same pictures either way."""

import os
import subprocess
import sys

import numpy as np

from renderer import user_cache
from renderer.envmap import read_hdr_image
from renderer.lighting import glossiness
from renderer.lighting.filters import Filter


def _render(tmp_path, cache, out: str, *extra: str) -> str:
    env = {**os.environ, user_cache.ENV_VAR: str(cache)}
    done = subprocess.run([sys.executable, "-m", "renderer.cli", "render", "--preset", "fast", "--size", "40x40",
                           "--exr", str(tmp_path / out), *extra], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_second_render_reads_the_pem_set_and_draws_the_same_picture(tmp_path):
    cache = tmp_path / "cache"
    first = _render(tmp_path, cache, "a.exr")
    assert "PEM build" in first, first
    assert len(list((cache / "pem-sets").glob("*.npz"))) == 1
    for folder in ("lobe-tables", "weight-chains", "cubes"):   # the calibration, the PEMs' normalizer, the map
        assert list((cache / folder).glob("*.npz")), folder
    assert len(list((cache / "cubes").glob("*.npz"))) == 1      # the PEMs' cube (a lat-long's background reads the source)
    second = _render(tmp_path, cache, "b.exr")
    assert "PEM set from the cache folder" in second, second
    np.testing.assert_array_equal(read_hdr_image(tmp_path / "a.exr"), read_hdr_image(tmp_path / "b.exr"))
    # --no-cache builds and stores nothing.
    other = tmp_path / "other"
    assert "PEM build" in _render(tmp_path, other, "c.exr", "--no-cache")
    assert not (other / "pem-sets").exists()
    np.testing.assert_array_equal(read_hdr_image(tmp_path / "a.exr"), read_hdr_image(tmp_path / "c.exr"))


def test_a_lobe_table_read_back_is_the_one_built_and_a_bad_entry_is_built_anew(tmp_path, monkeypatch):
    monkeypatch.setenv(user_cache.ENV_VAR, str(tmp_path))
    glossiness.lobe_table.cache_clear()
    try:
        built = glossiness.lobe_table(16, Filter.SQRT_COSINE)       # built and stored
        (entry,) = (tmp_path / "lobe-tables").glob("16-sqrt-cosine-*.npz")
        glossiness.lobe_table.cache_clear()
        read = glossiness.lobe_table(16, Filter.SQRT_COSINE)        # read back
        for g in (0.0, 0.3, 0.8, 0.97, 1.0):
            assert read.level_for_glossiness(g, "l2") == built.level_for_glossiness(g, "l2")
            assert read.level_for_glossiness(g, "volume") == built.level_for_glossiness(g, "volume")
        np.testing.assert_array_equal(read.responses, built.responses)
        assert len(read.l2_terms) == len(built.l2_terms) == 5
        entry.write_bytes(b"not an npz")                             # a truncated or foreign entry
        glossiness.lobe_table.cache_clear()
        again = glossiness.lobe_table(16, Filter.SQRT_COSINE)
        assert again.level_for_glossiness(0.8, "l2") == built.level_for_glossiness(0.8, "l2")
        with np.load(entry) as data:                                 # and replaced
            assert "responses" in data.files
    finally:
        glossiness.lobe_table.cache_clear()


def test_a_cache_folder_keeps_within_its_bytes_least_recently_used_first(tmp_path):
    def entry(name):
        return user_cache.load_or_build(tmp_path / f"{name}.npz", lambda: {"a": np.full(1000, ord(name[0]), np.float64)},
                                        max_bytes=20_000)

    entry("a")
    entry("b")
    os.utime(tmp_path / "a.npz", (0, 0))   # a: the least recently used
    entry("c")                              # three of ~8 kB each: a goes
    assert sorted(p.stem for p in tmp_path.glob("*.npz")) == ["b", "c"]
    def never():
        raise AssertionError("built, not read back")

    assert user_cache.load_or_build(tmp_path / "b.npz", never)["a"][0] == ord("b")


def test_a_mesh_file_read_again_comes_from_its_parse_and_a_changed_file_is_parsed_anew(tmp_path):
    from renderer.mesh import load_mesh
    from renderer.mesh_cache import load_mesh_cached

    cache = tmp_path / "meshes"
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    first = load_mesh_cached(path, up="z", scale=2.0, cache=cache)
    (entry,) = cache.glob("*.npz")
    again = load_mesh_cached(path, up="z", scale=2.0, cache=cache)     # read back: the same mesh
    plain = load_mesh(path, up="z", scale=2.0)                          # and trimesh's own parse
    for m in (again, plain):
        np.testing.assert_array_equal(m.positions, first.positions)
        np.testing.assert_array_equal(m.faces, first.faces)
        np.testing.assert_array_equal(m.uvs, first.uvs)
    assert np.abs(first.positions).max() == 2.0
    assert len(list(cache.glob("*.npz"))) == 1
    load_mesh_cached(path, up="y", scale=2.0, cache=cache)       # another up axis: another entry
    assert len(list(cache.glob("*.npz"))) == 2
    path.write_text("v 0 0 0\nv 3 0 0\nv 0 3 0\nf 1 2 3\n")      # another file at the same path
    changed = load_mesh_cached(path, cache=cache)
    assert changed.n_faces == 1 and changed.positions.max() == 3.0 and changed.uvs is None
    assert len(list(cache.glob("*.npz"))) == 3
    entry.write_bytes(b"not an npz")                              # a bad entry is parsed anew
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    np.testing.assert_array_equal(load_mesh_cached(path, up="z", scale=2.0, cache=cache).positions, first.positions)


def test_a_meshs_convexity_is_judged_once_and_read_back(tmp_path, monkeypatch):
    from conftest import sphere

    from renderer.mesh import Mesh
    from renderer.scene import convex_surface

    monkeypatch.setenv(user_cache.ENV_VAR, str(tmp_path))
    ball = sphere(1.0, subdivisions=2)
    sheet = Mesh.from_arrays(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
    assert convex_surface(ball.positions, ball.faces) and not convex_surface(sheet.positions, sheet.faces)
    entries = sorted((tmp_path / "convexity").glob("*.npz"))
    assert len(entries) == 2
    for e in entries:   # the verdicts turned round: read back, not judged again
        with np.load(e) as data:
            verdict = bool(data["convex"])
        np.savez(e, convex=np.array(not verdict))
    assert not convex_surface(ball.positions, ball.faces) and convex_surface(sheet.positions, sheet.faces)
