"""Shared fixtures. One GL context per test session, created here only (moderngl's advice), used
from the main thread; tests that need ../shared/assets skip with the reason when it is absent."""

from __future__ import annotations

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
