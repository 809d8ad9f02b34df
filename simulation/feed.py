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

from service.client import FrameResult, RenderClient

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


def upload_studio_environment(client: RenderClient, width: int = 1024) -> dict:
    """Upload the bundled procedural photo studio (renderer/envmap/procedural.py) as an EXR."""
    from renderer.envmap import studio_environment, write_exr

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "studio.exr"
        write_exr(path, studio_environment(width))
        return client.upload_environment(path.read_bytes(), name="studio (bundled)")


@dataclass
class DrapeFeed:
    """Registers one scene per view (garment = the cloth, body = the proxy's mesh and the floor) and
    posts the cloth's current positions to each. `format`: png | exr | json (the answer's image)."""

    client: RenderClient
    sim: ClothSim
    environment_id: str
    views: tuple[View, ...] = (FRONT,)
    quality: dict = field(default_factory=lambda: {"preset": "fast"})
    output: dict = field(default_factory=lambda: {"width": 512, "height": 512})
    format: str = "png"
    name: str = "drape"
    scene_ids: list[str] = field(default_factory=list)

    def __post_init__(self):
        body_positions, body_faces = self.sim.body.mesh()
        cloth = self.sim.cloth
        for view in self.views:
            scene = self.client.create_scene(
                self.environment_id, name=f"{self.name} ({view.name})", up="y",
                positions=self.sim.positions, faces=cloth.faces, uvs=cloth.uvs, material=GARMENT_MATERIAL,
                body=self.client.mesh_spec(body_positions, body_faces, material=BODY_MATERIAL, name="body"),
                camera=view.camera(), quality=self.quality, output=self.output)
            self.scene_ids.append(scene["id"])

    def post(self, frame_index: int, positions: np.ndarray | None = None) -> list[FrameResult]:
        """Send one frame (default: the simulation's current positions) to every view's scene."""
        p = self.sim.positions if positions is None else positions
        return [self.client.send_frame(sid, p, format=self.format, frame_index=frame_index)
                for sid in self.scene_ids]

    def close(self) -> None:
        """Delete the scenes (their GPU resources are released on the service)."""
        for sid in self.scene_ids:
            self.client.delete_scene(sid)
        self.scene_ids.clear()
