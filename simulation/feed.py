"""The simulator as a client of the render service: register the environment, the body and the
garment once, then post each simulated frame's positions over HTTP and collect what came back.

    with RenderClient(url) as client:
        feed = DrapeFeed(client, sim, environment_id=env["id"])
        for k in range(n):
            sim.step_frame()
            results = feed.post(k)       # one FrameResult per view
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from garment_render_client import FrameResult, RenderClient

from .panels import Garment
from .solver import ClothSim


@dataclass(frozen=True)
class View:
    """A camera on the scene: a scene is registered per view. eye, target in metres, Y-up."""

    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_y_deg: float = 38.0

    def camera(self) -> dict:
        return {"eye": list(self.eye), "target": list(self.target), "up": [0.0, 1.0, 0.0], "fov_y_deg": self.fov_y_deg}


FRONT = View("front", eye=(0.9, 1.55, 3.1))
THREE_QUARTER = View("three-quarter", eye=(-2.4, 1.9, 2.2), target=(0.0, 0.95, 0.0))

# Satin-like red cloth; matte grey body and floor.
GARMENT_MATERIAL = {"albedo": [0.55, 0.06, 0.07], "specular": 0.35, "glossiness": 0.75}
BODY_MATERIAL = {"albedo": [0.62, 0.60, 0.58], "specular": 0.05, "glossiness": 0.3}
FLOOR_MATERIAL = {"albedo": [0.45, 0.45, 0.45], "specular": 0.0, "glossiness": 0.3}


def upload_studio_environment(client: RenderClient, width: int = 1024) -> dict:
    """Upload the bundled procedural photo studio (renderer/envmap/procedural.py) as an EXR."""
    from renderer.envmap import studio_environment, write_exr

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "studio.exr"
        write_exr(path, studio_environment(width))
        return client.upload_environment(path.read_bytes(), name="studio (bundled)")


@dataclass
class DrapeFeed:
    """Registers one scene per view and posts the cloth's current positions to each. The garment is
    the simulated cloth, or with `garment` (a sewn `panels.Garment`) its render mesh, seams merged;
    the body is `body` (positions, faces) or else the proxy's capsules with their floor quad, and
    `floor` (positions, faces) a floor that takes shadows and casts none. `format`: png | exr | json
    (the answer's image)."""

    client: RenderClient
    sim: ClothSim
    environment_id: str
    views: tuple[View, ...] = (FRONT,)
    quality: dict = field(default_factory=lambda: {"preset": "fast"})
    output: dict = field(default_factory=lambda: {"width": 512, "height": 512})
    format: str = "png"
    name: str = "drape"
    garment: Garment | None = None
    body: tuple[np.ndarray, np.ndarray] | None = None
    floor: tuple[np.ndarray, np.ndarray] | None = None
    scene_ids: list[str] = field(default_factory=list)

    def __post_init__(self):
        body_positions, body_faces = self.body if self.body is not None else self.sim.body.mesh()
        positions, faces, uvs = self._render_mesh(self.sim.x)
        extra = {}
        if self.floor is not None:
            extra["floor"] = self.client.mesh_spec(*self.floor, material=FLOOR_MATERIAL, name="floor")
        for view in self.views:
            scene = self.client.create_scene(
                self.environment_id, name=f"{self.name} ({view.name})", up="y",
                positions=positions, faces=faces, uvs=uvs, material=GARMENT_MATERIAL,
                body=self.client.mesh_spec(body_positions, body_faces, material=BODY_MATERIAL, name="body"),
                camera=view.camera(), quality=self.quality, output=self.output, **extra)
            self.scene_ids.append(scene["id"])

    def _render_mesh(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.garment is not None:
            return self.garment.sewn(x)
        return np.asarray(x, np.float32), self.sim.cloth.faces, self.sim.cloth.uvs

    def post(self, frame_index: int, positions: np.ndarray | None = None) -> list[FrameResult]:
        """Send one frame (default: the simulation's current positions) to every view's scene."""
        p = self._render_mesh(self.sim.x if positions is None else positions)[0]
        return [self.client.send_frame(sid, p, format=self.format, frame_index=frame_index)
                for sid in self.scene_ids]

    def close(self) -> None:
        """Delete the scenes (their GPU resources are released on the service)."""
        for sid in self.scene_ids:
            self.client.delete_scene(sid)
        self.scene_ids.clear()
