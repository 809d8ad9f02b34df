"""The service's codecs without a server: the fast PNG writer gives exactly the renderer's 8-bit
encoding, frame bodies are validated and decoded as documented, uploads are sniffed correctly."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import assert_rec709_exr, assert_tagged_srgb, png_chunks
from PIL import Image

from renderer.errors import MeshError
from renderer.mesh import vertex_normals, z_up_to_y_up
from renderer.shading.tonemap import ToneCurve, auto_exposure_ev, encode_rgba8, to_png_bytes
from service.codecs import (
    decode_frame,
    encode_exr,
    encode_png,
    frame_exposure_ev,
    hdr_dimensions,
    parse_layout,
    png_bytes,
    sniff_hdr_kind,
)
from service.errors import InvalidRequestError
from service.registry import SceneMeshInfo


def _image(h=48, w=40, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 4), np.float32)
    img[..., :3] = rng.gamma(0.5, 2.0, (h, w, 3))  # HDR-ish, with a few large values
    img[..., 3] = rng.random((h, w)) > 0.3
    return img


@pytest.mark.parametrize("channels", [3, 4])
def test_png_writer_round_trips_through_pillow(channels):
    rng = np.random.default_rng(1)
    pixels = rng.integers(0, 256, (37, 53, channels), dtype=np.uint8)
    for level in (0, 1, 9):
        decoded = np.asarray(Image.open(io.BytesIO(png_bytes(pixels, level))))
        assert decoded.shape == pixels.shape and np.array_equal(decoded, pixels)


@pytest.mark.parametrize("opaque", [True, False])
@pytest.mark.parametrize("tone", [c.value for c in ToneCurve])
def test_encode_png_matches_the_renderers_encoding(opaque, tone):
    img = _image()
    png, ev = encode_png(img, 0.7, tone, opaque)
    assert ev == 0.7
    expected = encode_rgba8(img, 0.7, tone)
    got = np.asarray(Image.open(io.BytesIO(png)))
    assert np.array_equal(got, expected[..., :3] if opaque else expected)


@pytest.mark.parametrize("channels", [3, 4])
def test_service_pngs_are_tagged_srgb_like_the_renderers(channels):
    """The hand-written PNG carries the same colour chunks as Pillow's (the CLI's), before the image data."""
    pixels = np.random.default_rng(2).integers(0, 256, (9, 11, channels), dtype=np.uint8)
    data = png_bytes(pixels)
    assert_tagged_srgb(data)
    colour = [c for c in png_chunks(data) if c[0] in (b"sRGB", b"gAMA", b"cHRM", b"iCCP")]
    assert colour == [c for c in png_chunks(to_png_bytes(_image(4, 4))) if c[0] in (b"sRGB", b"gAMA", b"cHRM", b"iCCP")]
    assert_tagged_srgb(encode_png(_image(), None, "pbr-neutral", opaque=True)[0])


def test_service_exrs_state_rec709_chromaticities():
    img = _image(6, 5)
    data = encode_exr(img)
    assert_rec709_exr(data)
    import OpenEXR

    np.testing.assert_array_equal(OpenEXR.File(io.BytesIO(data)).channels()["RGBA"].pixels, img)


def test_region_previews_are_tagged_srgb():
    from renderer.envmap import texel_directions
    from service.previews import region_preview_png

    d = texel_directions(8)
    labels = (d[..., 1] > 0).astype(np.int32)
    directions = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    assert_tagged_srgb(region_preview_png(np.ones((6, 8, 8, 3), np.float32), labels, directions, np.ones((2, 3)), 64))


def test_subsampled_auto_exposure_is_close_to_the_full_one():
    # A smooth frame, like a render: the median of a quarter of the pixels is within a hundredth of a stop.
    y, x = np.mgrid[0:256, 0:256] / 256.0
    img = np.zeros((256, 256, 4), np.float32)
    img[..., :3] = (0.05 + 3.0 * x * y)[..., None] * np.array([1.0, 0.8, 0.6])
    img[..., 3] = (x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.16
    assert abs(frame_exposure_ev(img) - auto_exposure_ev(img[..., :3], img[..., 3])) < 0.01


def _scene(n_garment: int, n_body: int | None = None, up: str = "y"):
    from renderer.procedural import procedural_garment

    g = procedural_garment(8)
    meshes = [SceneMeshInfo("garment", "g", g.n_vertices, g.n_faces, True, g.faces)]
    if n_body is not None:
        meshes.append(SceneMeshInfo("body", "b", g.n_vertices, g.n_faces, False, g.faces))
    ns = SimpleNamespace(id="scn_test", up=up, meshes=meshes)
    ns.mesh = lambda role: next((m for m in meshes if m.role == role), None)
    return ns, g


def test_frame_layouts_are_validated():
    scene, _ = _scene(0)
    assert parse_layout(None, scene) == ["positions"]
    assert parse_layout(" positions , normals ", scene) == ["positions", "normals"]
    for bad, words in (("positions,positions", "twice"), ("normals", "no positions"), ("colour", "unknown block"),
                       ("body_positions", "no body")):
        with pytest.raises(InvalidRequestError, match=words):
            parse_layout(bad, scene)
    scene_b, _ = _scene(0, 0)
    assert parse_layout("positions,body_positions,body_normals", scene_b) == [
        "positions", "body_positions", "body_normals"]
    with pytest.raises(InvalidRequestError, match="body_normals without body_positions"):
        parse_layout("positions,body_normals", scene_b)


def test_decode_frame_rotates_z_up_and_computes_normals():
    scene, g = _scene(0, up="z")
    p_zup = np.asarray(g.positions)[:, [0, 2, 1]] * np.array([1, -1, 1], np.float32)  # some Z-up pose
    arrays = decode_frame(np.ascontiguousarray(p_zup, "<f4").tobytes(), ["positions"], scene)
    assert np.array_equal(arrays.positions[0], z_up_to_y_up(p_zup))
    assert np.allclose(arrays.normals[0], vertex_normals(arrays.positions[0], g.faces))


def test_decode_frame_messages_name_the_problem():
    scene, g = _scene(0)
    good = np.ascontiguousarray(g.positions, "<f4").tobytes()
    with pytest.raises(InvalidRequestError, match=f"{len(good) - 12} bytes.*expects {len(good)} bytes"):
        decode_frame(good[:-12], ["positions"], scene)
    bad = np.array(g.positions, np.float32)
    bad[3, 2] = np.nan
    with pytest.raises(MeshError, match="positions block.*NaN/Inf.*vertex 3"):
        decode_frame(bad.tobytes(), ["positions"], scene)
    normals = np.zeros_like(bad)
    with pytest.raises(MeshError, match="zero-length normals"):
        decode_frame(good + normals.tobytes(), ["positions", "normals"], scene)


def test_sniffing_uploads(tmp_path):
    from renderer.envmap import studio_environment, write_exr

    path = tmp_path / "m.exr"
    write_exr(path, studio_environment(64))
    data = path.read_bytes()
    assert sniff_hdr_kind(data) == "exr" and hdr_dimensions(data, "exr") == (64, 32)
    hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16 +X 32\n" + bytes(16 * 32 * 4)
    assert sniff_hdr_kind(hdr) == "hdr" and hdr_dimensions(hdr, "hdr") == (32, 16)
    with pytest.raises(InvalidRequestError, match="JPEG"):
        sniff_hdr_kind(b"\xff\xd8\xff\xe0" + bytes(20))
    assert hdr_dimensions(data[:10], "exr") is None
