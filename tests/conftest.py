"""Shared fixtures. One GL context per test session, created here only (moderngl's advice), used
from the main thread; tests that need ../shared/assets skip with the reason when it is absent."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from renderer.camera import Camera
from renderer.mesh import Mesh

ASSETS = Path(__file__).resolve().parents[1].parent / "shared" / "assets"


def pytest_configure(config):
    """One cache folder (renderer/user_cache.py) for the session and the processes it starts, never
    the user's own: its entries (lobe tables, PEM sets) are made once per run."""
    import os
    import tempfile

    if "GARMENT_RENDER_CACHE_DIR" not in os.environ:
        os.environ["GARMENT_RENDER_CACHE_DIR"] = tempfile.mkdtemp(prefix="garment-render-cache-")
HDRI = ASSETS / "hdri"
needs_assets = pytest.mark.skipif(not HDRI.is_dir(),
                                  reason=f"shared HDRI assets not found at {HDRI} (they live outside the repository)")


def asset(*parts: str) -> Path:
    path = ASSETS.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"needs the shared test assets ({path} not found; they live beside the repo in ../shared)")
    return path


@pytest.fixture(scope="session")
def renderer():
    from renderer.errors import GLContextError
    from renderer.renderer import Renderer

    try:
        r = Renderer()
    except GLContextError as exc:  # pragma: no cover - a machine without EGL
        pytest.fail(f"no OpenGL 4.5 context: {exc}")
    yield r
    r.release()


@pytest.fixture(scope="session")
def gl(renderer):
    return renderer.gl


def sun_sky_cube(face_size: int, sun_dir, sun_radiance: float = 2000.0, sun_radius_deg: float = 3.0,
                 sky=(0.2, 0.3, 0.5), ground=(0.1, 0.1, 0.1)) -> np.ndarray:
    """A cube map (6, F, F, 3) float32: uniform sky and ground with one small bright sun disc."""
    from renderer.envmap.cube import texel_directions

    d = texel_directions(face_size)
    s = np.asarray(sun_dir, np.float64)
    s /= np.linalg.norm(s)
    cube = np.where(d[..., 1:2] > 0, np.asarray(sky), np.asarray(ground)).astype(np.float32)
    cube[(d @ s) > np.cos(np.radians(sun_radius_deg))] = sun_radiance
    return cube


# -- shared test scenes --------------------------------------------------------------------------

# A camera on +Z looking at the origin, slightly from above.
CAM = Camera((0.0, 0.3, 3.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)


def balanced(width=512, height=512, **settings):
    """The balanced preset's FrameSettings (presets.resolve, as a request resolves it) with `settings`
    over it (quality settings and output options alike): what tests of the product's path render,
    where FrameSettings() is the paper's method."""
    from renderer import config
    from renderer.presets import resolve

    quality = {k: v for k, v in settings.items() if k in config.BY_NAME}
    output = {k: v for k, v in settings.items() if k not in quality}
    return resolve("balanced", quality).frame(width, height, **output)


def balanced_pems(**settings):
    """The balanced preset's PEMSettings with the quality `settings` over it (the whole chain)."""
    from renderer.presets import resolve

    return resolve("balanced", settings).pems(None)


def sphere(radius=0.5, *, centre=(0, 0, 0), subdivisions=4) -> Mesh:
    s = trimesh.creation.icosphere(subdivisions, radius)
    return Mesh.from_arrays(np.asarray(s.vertices) + centre, np.asarray(s.faces), name="sphere")


def plane(size=4.0, y=0.0) -> Mesh:
    h = size / 2
    v = np.array([[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]])
    return Mesh.from_arrays(v, np.array([[0, 2, 1], [0, 3, 2]]), name="plane")


def covered(frame) -> np.ndarray:
    """Pixels a mesh covers (alpha > 0.5) of a rendered or reference frame."""
    return frame.image[..., 3] > 0.5


@pytest.fixture(scope="module")
def http(server):
    """An HTTP client of the module's `server` fixture (a real service: tests/service_server.py)."""
    import httpx

    with httpx.Client(base_url=server.url, timeout=120) as c:
        yield c


# -- colour metadata of the files the project writes ------------------------------------------------

def png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """The (type, data) of every chunk of a PNG, in file order, each chunk's CRC checked."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, at = [], 8
    while at < len(data):
        (n,), kind = struct.unpack(">I", data[at:at + 4]), data[at + 4:at + 8]
        body = data[at + 8:at + 8 + n]
        assert struct.unpack(">I", data[at + 8 + n:at + 12 + n])[0] == zlib.crc32(kind + body), kind
        chunks.append((kind, body))
        at += 12 + n
    return chunks


# What a PNG of sRGB pixels carries (PNG specification, 11.3.3.5): sRGB with perceptual intent, and
# the gAMA and cHRM an encoder writes beside it for decoders that ignore sRGB.
SRGB_CHUNKS = [(b"sRGB", b"\x00"), (b"gAMA", struct.pack(">I", 45455)),
               (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))]


def assert_tagged_srgb(data: bytes) -> None:
    """The PNG says its pixels are sRGB: the chunks before the first IDAT, and what Pillow reads."""
    from PIL import Image

    chunks = png_chunks(data)
    kinds = [k for k, _ in chunks]
    before = chunks[:kinds.index(b"IDAT")]
    for chunk in SRGB_CHUNKS:
        assert chunk in before, chunk[0]
    info = Image.open(io.BytesIO(data)).info
    assert info["srgb"] == 0 and info["gamma"] == pytest.approx(1 / 2.2, abs=1e-5)
    np.testing.assert_allclose(info["chromaticity"], [0.3127, 0.329, 0.64, 0.33, 0.3, 0.6, 0.15, 0.06])


def assert_rec709_exr(source) -> None:
    """An EXR (a path or its bytes) states Rec. 709 primaries and D65 white: OpenEXR reads its
    chromaticities as the linear Rec. 709 colour space's (colorInteropID lin_rec709_scene)."""
    import OpenEXR

    f = OpenEXR.File(io.BytesIO(source) if isinstance(source, bytes) else str(source), header_only=True)
    chroma = f.header()["chromaticities"]
    np.testing.assert_allclose(chroma, [0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290], atol=1e-6)
    assert OpenEXR.chromaticitiesToColorInteropID(chroma) == "lin_rec709_scene"
