"""A Python client for simulators: upload an environment map, register a scene, then send each
simulation frame's positions (numpy in) and get the image (numpy or PIL out) with its timings.

    from garment_render_client import RenderClient
    with RenderClient("http://127.0.0.1:8000", token=None) as c:
        env = c.upload_environment("studio.exr")
        scene = c.create_scene(env["id"], faces=faces, positions=p0, up="z",
                               material={"albedo": [0.8, 0.2, 0.2], "specular": 0.5, "glossiness": 0.8},
                               quality={"preset": "fast"}, output={"width": 512, "height": 512})
        for p in simulation:                                  # (V, 3) float32 per frame
            frame = c.send_frame(scene["id"], p)
            frame.array(), frame.pil(), frame.timings       # uint8 (H, W, 3|4); PIL image; {stage: ms}

A 503 (queue full, not ready, a scale-out replica lost) is retried after its Retry-After delay, up to
`max_retries` times (a lost replica's not for a scene's registration); a
connection that fails before any answer came (a keep-alive connection the server had just closed, a
reset), or answered by a proxy in front of the service (a 5xx that is not the service's JSON), is
retried up to `max_transport_retries` times for every request but a scene's registration,
which is not idempotent (a retry could register it twice). Other errors raise `ServiceError` with the
service's message.

It needs numpy and httpx alone; `FrameResult.pil()` needs Pillow (the `pil` extra), `.array()` of an EXR
frame OpenEXR (the `exr` extra), and `stream_usd` the renderer's USD reader (the server's package,
garment-render, which includes this client).
"""

from __future__ import annotations

import base64
import io
import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

# A scene's URL: with Ray Serve, its id routes the request (the multiplexed model id).
SCENE_URL = re.compile(r"^/scenes/([^/?]+)")

OCTET = "application/octet-stream"


class ServiceError(Exception):
    """An error answer: status, the service's machine-readable code and its message."""

    def __init__(self, status: int, code: str, detail: str):
        super().__init__(f"{status} {code}: {detail}")
        self.status, self.code, self.detail = status, code, detail


def parse_server_timing(header: str | None) -> dict[str, float]:
    out: dict[str, float] = {}
    for part in (header or "").split(","):
        name, _, params = part.strip().partition(";")
        for p in params.split(";"):
            k, _, v = p.strip().partition("=")
            if k == "dur" and name:
                out[name] = float(v)
    return out


@dataclass
class FrameResult:
    """One rendered frame. content: PNG or EXR bytes; timings: per-stage milliseconds."""

    content: bytes
    media_type: str
    timings: dict[str, float]
    headers: dict = field(default_factory=dict)
    retries: int = 0

    @property
    def frame_index(self) -> int | None:
        v = self.headers.get("x-frame-index")
        return int(v) if v is not None else None

    def pil(self):
        """A PIL image (PNG frames only)."""
        try:
            from PIL import Image
        except ImportError as e:
            raise ImportError('FrameResult.pil() needs Pillow: pip install "garment-render-client[pil]"') from e
        if self.media_type != "image/png":
            raise ValueError(f"pil() needs a PNG frame, this one is {self.media_type}")
        return Image.open(io.BytesIO(self.content))

    def array(self) -> np.ndarray:
        """PNG: uint8 (H, W, 3) sRGB, or (H, W, 4) with coverage alpha. EXR: float32 (H, W, 4) linear RGBA."""
        if self.media_type == "image/x-exr":
            try:
                import OpenEXR
            except ImportError as e:
                raise ImportError('FrameResult.array() of an EXR frame needs OpenEXR: '
                                  'pip install "garment-render-client[exr]"') from e
            f = OpenEXR.File(io.BytesIO(self.content))
            ch = f.channels()
            if "RGBA" in ch:
                return np.asarray(ch["RGBA"].pixels, np.float32)
            return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGBA"], -1)
        return np.asarray(self.pil())


def _from_service(r: httpx.Response) -> bool:
    """An answer of the service's (its errors are JSON with a code), not of a proxy in front of it."""
    try:
        return "code" in r.json()
    except (json.JSONDecodeError, ValueError, TypeError):
        return False


def _replica_lost(r: httpx.Response) -> bool:
    """A 503 saying the replica went while it held the request (scale-out): sending it again is safe only
    where doing it twice does no harm."""
    try:
        return r.json().get("code") == "replica_lost"
    except (json.JSONDecodeError, ValueError, AttributeError):
        return False


def _as_f32(a, what: str) -> bytes:
    arr = np.ascontiguousarray(a, dtype="<f4")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must have shape (V, 3); got {arr.shape}")
    return arr.tobytes()


class RenderClient:
    def __init__(self, base_url: str, token: str | None = None, timeout: float = 300.0, max_retries: int = 50,
                 max_retry_wait_s: float = 5.0, http: httpx.Client | None = None, max_transport_retries: int = 3):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = http or httpx.Client(base_url=base_url, headers=headers, timeout=timeout)
        self.max_retries, self.max_retry_wait_s = max_retries, max_retry_wait_s
        self.max_transport_retries = max_transport_retries
        self.retries = 0  # 503 answers retried so far
        self.transport_retries = 0  # requests sent again after their connection failed without an answer

    def close(self) -> None:
        self.http.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- plumbing ----------------------------------------------------------------------------------
    def _request(self, method: str, url: str, idempotent: bool = True, **kw) -> tuple[httpx.Response, int]:
        retries = failed = 0
        scene = SCENE_URL.match(url)
        if scene:   # Ray Serve's replicas route by it to the one holding the scene (service/ray_serve.py)
            kw["headers"] = {**(kw.get("headers") or {}), "serve_multiplexed_model_id": scene.group(1)}
        while True:
            try:
                r = self.http.request(method, url, **kw)
            except (httpx.RemoteProtocolError, httpx.ReadError, httpx.WriteError, httpx.ConnectError):
                # No answer came: the request may be sent again if doing it twice does no harm.
                if not idempotent or failed >= self.max_transport_retries:
                    raise
                failed += 1
                self.transport_retries += 1
                time.sleep(0.05 * 2 ** failed)
                continue
            if (r.status_code >= 500 and not _from_service(r) and idempotent
                    and failed < self.max_transport_retries):
                # A proxy's own answer (a scale-out ingress that went): as if no answer came.
                failed += 1
                self.transport_retries += 1
                time.sleep(0.05 * 2 ** failed)
                continue
            if r.status_code == 503 and retries < self.max_retries and (idempotent or not _replica_lost(r)):
                retries += 1
                self.retries += 1
                wait = float(r.headers.get("retry-after", "1"))
                time.sleep(min(wait, self.max_retry_wait_s) * (0.5 + 0.5 * np.random.random()))
                continue
            if r.status_code >= 400:
                try:
                    body = r.json()
                    raise ServiceError(r.status_code, body.get("code", "?"), body.get("detail", r.text))
                except (json.JSONDecodeError, ValueError, AttributeError):
                    raise ServiceError(r.status_code, "?", r.text) from None
            return r, retries

    def _json(self, method: str, url: str, **kw):
        r, _ = self._request(method, url, **kw)
        return r.json() if r.content else None

    @staticmethod
    def _frame(r: httpx.Response, retries: int) -> FrameResult:
        mt = r.headers.get("content-type", "").split(";")[0]
        timings = parse_server_timing(r.headers.get("server-timing"))
        if mt == "application/json":
            body = r.json()
            img = body["image"]
            return FrameResult(base64.b64decode(img["base64"]), img["media_type"], body["timings_ms"],
                               dict(r.headers), retries)
        return FrameResult(r.content, mt, timings, dict(r.headers), retries)

    # -- operations --------------------------------------------------------------------------------
    def live(self) -> dict:
        return self._json("GET", "/health/live")

    def ready(self) -> bool:
        return self.http.get("/health/ready").status_code == 200

    def stats(self) -> dict:
        return self._json("GET", "/stats")

    def metrics(self) -> str:
        return self.http.get("/metrics").text

    def upload_environment(self, source: str | Path | bytes, layout: str = "auto", repair: bool = False,
                           name: str | None = None, **quality) -> dict:
        """source: a path to an .exr/.hdr file or its bytes. quality: preset, lights, face_size, filter, levels."""
        data = Path(source).read_bytes() if isinstance(source, (str, Path)) else bytes(source)
        if name is None and isinstance(source, (str, Path)):
            name = Path(source).name
        params = {"layout": layout, "repair": str(repair).lower(), **{k: v for k, v in quality.items() if v is not None}}
        if name:
            params["name"] = name
        return self._json("POST", "/environments", params=params, content=data, headers={"Content-Type": OCTET})

    def environment(self, env_id: str) -> dict:
        return self._json("GET", f"/environments/{env_id}")

    def upload_mesh(self, source: str | Path | bytes, format: str | None = None, up: str = "y",
                    scale: float = 1.0) -> dict:
        if isinstance(source, (str, Path)):
            format = format or Path(source).suffix.lstrip(".").lower()
            data = Path(source).read_bytes()
        else:
            data = bytes(source)
        if not format:
            raise ValueError("give the mesh format (obj, ply, glb, gltf, stl)")
        return self._json("POST", "/meshes", params={"format": format, "up": up, "scale": scale}, content=data,
                          headers={"Content-Type": OCTET})

    def upload_fabric(self, source: str | Path | bytes, name: str | None = None) -> dict:
        """source: a U3M archive (.u3ma), a path or its bytes. Returns the fabric's details (its `id`
        for `fabric_id` and colourways); the same file uploaded again is found, not read again."""
        data = Path(source).read_bytes() if isinstance(source, (str, Path)) else bytes(source)
        if name is None and isinstance(source, (str, Path)):
            name = Path(source).name
        return self._json("POST", "/fabrics", params={"name": name} if name else {}, content=data,
                          headers={"Content-Type": "application/zip"})

    def fabric(self, fabric_id: str) -> dict:
        """Every field of every face of an uploaded fabric: a constant, or a texture with its size."""
        return self._json("GET", f"/fabrics/{fabric_id}")

    def fabrics(self) -> list[dict]:
        return self._json("GET", "/fabrics")

    def delete_fabric(self, fabric_id: str) -> None:
        """Refused (ServiceError 409) while a scene uses the fabric."""
        self._request("DELETE", f"/fabrics/{fabric_id}")

    @staticmethod
    def mesh_spec(positions=None, faces=None, uvs=None, material: dict | None = None, mesh_id: str | None = None,
                  name: str | None = None, fabric_id: str | None = None,
                  uv_scale: tuple[float, float] | None = None) -> dict:
        """A mesh of a scene: its vertices (or an uploaded `mesh_id`) and either a `material` or an
        uploaded fabric's `fabric_id` (the mesh needs UVs; `uv_scale`, the metres a UV unit spans,
        measured on the mesh when not given)."""
        if fabric_id is not None and material is not None:
            raise ValueError("give either material or fabric_id, not both")
        if uv_scale is not None and fabric_id is None:
            raise ValueError("uv_scale places a fabric's textures: it needs fabric_id")
        spec: dict = {"fabric_id": fabric_id} if fabric_id is not None else {"material": material or {}}
        if uv_scale is not None:
            spec["uv_scale"] = [float(uv_scale[0]), float(uv_scale[1])]
        if mesh_id is not None:
            spec["mesh_id"] = mesh_id
        else:
            spec["positions"] = np.asarray(positions, np.float64).tolist()
            spec["faces"] = np.asarray(faces, np.int64).tolist()
            if uvs is not None:
                spec["uvs"] = np.asarray(uvs, np.float64).tolist()
        if name:
            spec["name"] = name
        return spec

    def scene_spec(self, environment_id: str, positions=None, faces=None, uvs=None, material: dict | None = None,
                   mesh_id: str | None = None, body: dict | None = None, camera: dict | None = None,
                   quality: dict | None = None, output: dict | None = None, up: str = "y",
                   name: str = "scene", floor: dict | None = None, fabric_id: str | None = None,
                   uv_scale: tuple[float, float] | None = None, colourways: list | None = None) -> dict:
        """colourways: materials (dicts) or fabrics ({"fabric_id": ..., "uv_scale": ...}) the views
        route renders from the same frame."""
        spec = {"name": name, "environment_id": environment_id, "up": up,
                "garment": self.mesh_spec(positions, faces, uvs, material, mesh_id, name="garment",
                                          fabric_id=fabric_id, uv_scale=uv_scale),
                "quality": quality or {}, "output": output or {}}
        if colourways is not None:
            spec["colourways"] = list(colourways)
        if body is not None:
            spec["body"] = body
        if floor is not None:
            spec["floor"] = floor
        if camera is not None:
            spec["camera"] = camera
        return spec

    def create_scene(self, environment_id: str, **kw) -> dict:
        """kw: positions, faces, uvs, material or fabric_id (and uv_scale), mesh_id, body and floor
        (mesh_spec dicts), camera, quality, output, up, name, colourways."""
        return self._json("POST", "/scenes", idempotent=False, json=self.scene_spec(environment_id, **kw))

    def add_colourway(self, scene_id: str, material: dict | None = None, fabric_id: str | None = None,
                      uv_scale: list[float] | None = None) -> dict:
        """One more garment material (`material`, a MaterialSpec dict) or uploaded fabric (`fabric_id`,
        optionally `uv_scale`) for a registered scene; returns the scene, whose `colourways` is the new
        one's index (the views route's `colourway`; send_views renders every colourway)."""
        if (material is None) == (fabric_id is None):
            raise ValueError("give a material or a fabric_id")
        body = material if material is not None else {"fabric_id": fabric_id, **({"uv_scale": uv_scale} if uv_scale else {})}
        return self._json("POST", f"/scenes/{scene_id}/colourways", idempotent=False, json=body)

    def delete_scene(self, scene_id: str) -> None:
        self._request("DELETE", f"/scenes/{scene_id}")

    def send_frame(self, scene_id: str, positions, normals=None, body_positions=None, body_normals=None,
                   format: str = "png", exposure: float | None = None, frame_index: int | None = None,
                   environment_rotation: float | None = None) -> FrameResult:
        """positions: (V, 3) in the scene's up axis; the optional blocks follow the layout in codecs.py.
        environment_rotation: degrees the map turns about the up axis for this frame (None: the scene's)."""
        blocks, parts = [], []
        for name, a in (("positions", positions), ("normals", normals), ("body_positions", body_positions),
                        ("body_normals", body_normals)):
            if a is not None:
                blocks.append(name)
                parts.append(_as_f32(a, name))
        headers = {"Content-Type": OCTET, "X-Frame-Layout": ",".join(blocks)}
        if frame_index is not None:
            headers["X-Frame-Index"] = str(frame_index)
        params = {"format": format} if format else {}
        if exposure is not None:
            params["exposure"] = exposure
        if environment_rotation is not None:
            params["environment_rotation"] = environment_rotation
        r, retries = self._request("POST", f"/scenes/{scene_id}/frames", content=b"".join(parts), headers=headers,
                                   params=params)
        return self._frame(r, retries)

    def send_views(self, scene_id: str, positions, turntable: int | None = None, views: list[str] | None = None,
                   colourways: bool = True, exposure: float | None = None,
                   environment_rotation: float | None = None) -> FrameResult:
        """One frame's positions seen from several cameras (`turntable` N steps about the target, or
        named `views`: front, back, left, right, ...) and, with `colourways`, in every colourway the
        scene was registered with: one PNG sheet, a row per view and a column per colourway."""
        if (turntable is None) == (views is None):
            raise ValueError("give turntable=N or views=[...]: one of the two")
        params: dict = {"colourways": str(colourways).lower(), "format": "sheet"}
        if turntable is not None:
            params["turntable"] = int(turntable)
        else:
            params["views"] = ",".join(views)
        if exposure is not None:
            params["exposure"] = exposure
        if environment_rotation is not None:
            params["environment_rotation"] = environment_rotation
        r, retries = self._request("POST", f"/scenes/{scene_id}/frames/views", content=_as_f32(positions, "positions"),
                                   headers={"Content-Type": OCTET, "X-Frame-Layout": "positions"}, params=params)
        return self._frame(r, retries)

    def send_batch(self, scene_id: str, frames, image: str = "png") -> list[FrameResult]:
        """frames: (F, V, 3) garment positions. Returns one FrameResult per frame, in order."""
        arr = np.ascontiguousarray(frames, dtype="<f4")
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise ValueError(f"frames must have shape (F, V, 3); got {arr.shape}")
        r, retries = self._request("POST", f"/scenes/{scene_id}/frames/batch", content=arr.tobytes(),
                                   headers={"Content-Type": OCTET}, params={"format": "json", "image": image})
        return [FrameResult(base64.b64decode(f["image"]["base64"]), f["image"]["media_type"], f["timings_ms"],
                            {"x-frame-index": str(f["frame_index"])}, retries) for f in r.json()["frames"]]

    def stream_usd(self, path: str | Path, environment_id: str, material: dict | None = None,
                   body_material: dict | None = None, scale: float = 1.0, garment: str | None = None, **kw):
        """Play a USD stage's simulation through a new scene: its garment (`garment`, a glob over prim
        paths or names; default: the meshes that move) and its other meshes as the body, moving where
        they have frames (renderer/usd.py reads them in Y-up metres from the stage's metadata, times
        `scale`). Registers the scene with the first frame, then sends every frame; yields (scene id,
        frame index, FrameResult). kw: camera, quality, output, name (`scene_spec`)."""
        try:
            from renderer.mesh import concatenate
            from renderer.sequence import read_usd_sequence
        except ImportError as e:
            raise ImportError("stream_usd reads the stage with the renderer's USD reader, which comes with the "
                              "server's package (garment-render); without it, read the stage yourself and send "
                              "each frame with send_frame") from e

        seq = read_usd_sequence(path, scale, garment)
        body, body_frames = None, None
        if seq.extras:   # one body of every other mesh, its frames where any of them moves
            positions, faces = concatenate((m.positions, m.faces) for m in seq.extras)
            body = self.mesh_spec(positions, faces, material=body_material, name="body")
            if any(f is not None for f in seq.extra_frames):
                body_frames, _ = concatenate((np.broadcast_to(m.positions, (seq.n_frames, *m.positions.shape))
                                              if f is None else f, m.faces) for m, f in zip(seq.extras, seq.extra_frames))
        scene = self.create_scene(environment_id, positions=seq.positions[0], faces=seq.faces, material=material,
                                  body=body, up="y", **kw)
        for k in range(seq.n_frames):
            yield scene["id"], k, self.send_frame(scene["id"], seq.positions[k], frame_index=k,
                                                  body_positions=None if body_frames is None else body_frames[k])

    def render_once(self, spec: dict, format: str = "png") -> FrameResult:
        """Stateless render of a whole scene (a `scene_spec(...)` dict)."""
        r, retries = self._request("POST", "/render", json=spec, params={"format": format})
        return self._frame(r, retries)
