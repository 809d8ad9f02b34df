"""A quick still of a garment on the mannequin with the project's renderer (needs an OpenGL 4.5
context, EGL): garment and body cast shadows, the floor only receives them.

The views are the demo's (`feed.FRONT`, `feed.THREE_QUARTER`); the quality is the "fast" preset
under the bundled procedural studio.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

GARMENT_ALBEDO = (0.55, 0.06, 0.07)
BODY_ALBEDO = (0.62, 0.60, 0.58)
FLOOR_ALBEDO = (0.45, 0.45, 0.45)


def render_preview(out: Path | str, garment: tuple[np.ndarray, np.ndarray, np.ndarray],
                   body: tuple[np.ndarray, np.ndarray], floor: tuple[np.ndarray, np.ndarray],
                   views: list[tuple[tuple[float, float, float], tuple[float, float, float]]],
                   height: int = 512, fov_y_deg: float = 38.0) -> Path:
    """Render one PNG with the views side by side, each height x height pixels, one exposure for
    all. garment: (positions (V, 3), faces (F, 3), uvs (V, 2)); body, floor: (positions, faces);
    metres, Y-up, faces counter-clockwise seen from outside. views: (eye, target) per view,
    metres."""
    import renderer as gr
    from renderer.envmap import studio_environment
    from renderer.shading.tonemap import DEFAULT_CURVE, auto_exposure_ev

    w = h = int(height)
    quality = gr.quality("fast")
    env = gr.environment_from_array(studio_environment(1024), "latlong", quality.face_size, name="studio (bundled)")
    meshes = [gr.Mesh.from_arrays(*garment, name="garment"), gr.Mesh.from_arrays(*body, name="body"),
              gr.Mesh.from_arrays(*floor, name="floor")]
    materials = [gr.Material(GARMENT_ALBEDO, 0.35, 0.75), gr.Material(BODY_ALBEDO, 0.05, 0.3),
                 gr.Material(FLOOR_ALBEDO, 0.0, 0.2)]
    settings = quality.frame(w, h, background=gr.Background.BLACK)
    images = []
    with gr.Renderer() as r:
        pems = r.pem_set(env, quality.pems(materials=materials))
        scene = r.create_scene(meshes, materials, casters=[True, True, False])
        for eye, target in views:
            frame = r.render(scene, pems, settings, gr.Camera(eye, target, fov_y_deg=fov_y_deg))
            images.append(frame.image)
        scene.release()
        pems.release()
    img = np.concatenate(images, axis=1)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    gr.write_png(out, img, auto_exposure_ev(img[..., :3], img[..., 3]), DEFAULT_CURVE)
    return out
