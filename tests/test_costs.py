"""renderer/costs.py against what a frame really allocates: every preset's shadow-map arrays, render
targets and PEM set, measured from the renderer's own GL objects after a frame, at the sizes the README
names, on a map with a sun (sharp maps, shared) and one without."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import sun_sky_cube

from renderer.costs import frame_cost, plan_maps
from renderer.presets import PRESET_NAMES, resolve
from renderer.procedural import default_scene
from renderer.shading.material import Material

DTYPE_BYTES = {"f1": 1, "u1": 1, "i1": 1, "f2": 2, "u2": 2, "i2": 2, "f4": 4, "u4": 4, "i4": 4}


def gl_bytes(obj) -> int:
    """Bytes of a moderngl texture, texture array or renderbuffer from its own size, format and
    samples (its MIP levels, where it has any, are counted by ShadowMaps.nbytes)."""
    if obj is None:
        return 0
    return (obj.width * obj.height * getattr(obj, "layers", 1) * obj.components * DTYPE_BYTES[obj.dtype]
            * max(getattr(obj, "samples", 0), 1))


def measured(renderer, settings, pems) -> dict:
    """What the frame just rendered holds: its shadow-map arrays (ShadowMaps.nbytes, and their textures'
    own sizes where they carry no MIP chain), its render targets and the still meshes' targets of its
    size (an earlier frame's of another size may linger), and the PEM set."""
    arrays = dict(renderer._shadow_maps)
    for maps in arrays.values():
        if not maps.mipmapped:
            assert maps.nbytes == gl_bytes(maps.moments) + gl_bytes(maps.scratch)
    t = renderer._target
    assert t.key[:2] == (settings.width, settings.height)
    targets = sum(gl_bytes(o) for o in (t.color, t.depth, *t.gbuf, t.ms_depth, t.final, t.edge_marks))
    w, h = settings.width, settings.height
    still = sum(gl_bytes(o) for st in renderer._still_targets.values()
                if st.shape[:2] == (w, h) and st.shape[3] in (0, settings.aa_samples if settings.aa_samples > 1 else -1)
                for o in (st.depth, *st.textures))
    return {"main": arrays["main"].nbytes, "sharp": arrays["sharp"].nbytes if "sharp" in arrays else 0,
            "targets": targets + still, "pem": pems.nbytes}


def render_fresh(renderer, scene, pems, settings):
    """A frame whose shadow-map arrays are its own: an array another test's frame left (one that made a
    MIP chain keeps it, unread) is given back first, as a service's first frame finds none."""
    for which in list(renderer._shadow_maps):
        renderer._shadow_maps.pop(which).release()
    return renderer.render(scene, pems, settings)


@pytest.fixture(scope="module")
def dress():
    """The bundled scene (garment, body and a floor that only receives): two shadow groups and still
    meshes, as a service's scene with a body has."""
    meshes, casters = default_scene()
    materials = [Material(albedo=np.array([0.8, 0.2, 0.2], np.float32), specular=np.float32(0.5),
                          glossiness=np.float32(0.8)) for _ in meshes]
    return meshes, casters, materials


# A sun split by the median cut into a few regions (sharp maps, sharing one) and a map without one.
MAPS = {"sun": lambda n: sun_sky_cube(n, (0.4, 0.8, 0.45), sun_radiance=5e4, sun_radius_deg=2.0),
        "sky": lambda n: sun_sky_cube(n, (0.0, 1.0, 0.0), sun_radiance=0.3, sun_radius_deg=20.0)}


@pytest.mark.gpu
@pytest.mark.parametrize("preset", PRESET_NAMES)
@pytest.mark.parametrize("size", [256, 512])
def test_the_estimate_is_what_a_frame_allocates(renderer, dress, preset, size):
    meshes, casters, materials = dress
    quality = resolve(preset)
    # Anti-aliased at 512 (the multisampled targets), as a request may ask whatever its preset.
    settings = replace(quality.frame(size, size), aa_samples=1 if size == 256 else 4)
    pem = quality.pems(None, materials)
    face = quality["face_size"]
    scene = renderer.create_scene(meshes, materials, casters=casters)
    try:
        for name, cube in MAPS.items():
            pems = renderer.build_pems(cube(face), pem)
            try:
                frame = render_fresh(renderer, scene, pems, settings)
                got = measured(renderer, settings, pems)
                cost = frame_cost(settings, pem, face, casters, regions=pems.regions)
                # The light plan's layout, as the frame counts it.
                assert (cost.main_layers, cost.sharp_layers) == (
                    max(frame.timings["shadow_layers"] - frame.timings["sharp_layers"], 1),
                    frame.timings["sharp_layers"]), name
                assert frame.settings["shadow_bytes"] == got["main"] + got["sharp"]
                want = {"main": cost.main_maps_bytes, "sharp": cost.sharp_maps_bytes, "targets": cost.targets_bytes,
                        "pem": cost.pem_bytes}
                total = sum(got.values())
                # The bound: within 1.5x of what the frame holds, and never below it.
                assert total <= cost.total_bytes <= 1.5 * total, (name, got, want)
                assert cost.exact and want == got, (name, got, want)
                # From the settings alone: at least what the frame holds, the least no more than it.
                bound = frame_cost(settings, pem, face, casters)
                assert bound.least_shadow_bytes <= cost.shadow_bytes <= bound.shadow_bytes, name
            finally:
                pems.release()
        if preset in ("balanced", "accurate"):   # the sun's regions got sharp maps, sharing some
            pems = renderer.build_pems(MAPS["sun"](face), pem)
            plan = plan_maps(pems.regions, settings)
            pems.release()
            assert 0 < len(plan.sharp_lights) < int(plan.sharp.sum())
    finally:
        scene.release()


def test_a_settings_bound_is_exact_without_sharp_maps_and_the_old_bound_was_not_the_frame(dress):
    """fast and paper have no sharp maps: their bound from the settings alone is the frame's own. The
    accurate preset's bound (as many sharp maps as 2.4 x the mean energy allows, 66 of 160) is not, and
    the service judges it on the PEM set's regions instead."""
    meshes, casters, materials = dress
    for preset in ("fast", "paper"):
        q = resolve(preset)
        cost = frame_cost(q.frame(256, 256), q.pems(None, materials), q["face_size"], casters)
        assert cost.exact and cost.least_shadow_bytes == cost.shadow_bytes
    q = resolve("accurate")
    bound = frame_cost(q.frame(256, 256), q.pems(None, materials), q["face_size"], casters)
    assert not bound.exact and bound.sharp_layers == 66 and bound.shadow_bytes > 4 << 30
    assert bound.least_shadow_bytes < 1 << 30


@pytest.mark.gpu
def test_the_estimate_holds_for_area_lights_penumbrae_and_physically_based_materials(renderer, dress):
    """The parts no preset uses: the main maps' MIP chains and caster shares (blocker penumbrae of area
    lights), the blur's scratch, the fifth G-buffer target of a physically based material."""
    meshes, casters, _ = dress
    materials = [Material(model="pbr", albedo=np.array([0.6, 0.5, 0.4], np.float32), roughness=np.float32(0.5))
                 for _ in meshes]
    quality = resolve("balanced", {"lights_from": "area", "penumbra": "blocker", "small_light_scale": 1,
                                   "blur_scale": 0.5, "lights": 24})
    settings = replace(quality.frame(256, 256), aa_samples=4)
    pem = quality.pems(None, materials)
    scene = renderer.create_scene(meshes, materials, casters=casters)
    pems = renderer.build_pems(MAPS["sun"](quality["face_size"]), pem)
    try:
        render_fresh(renderer, scene, pems, settings)
        got = measured(renderer, settings, pems)
        assert renderer._shadow_maps["main"].mipmapped and renderer._shadow_maps["main"].scratch is not None
        cost = frame_cost(settings, pem, quality["face_size"], casters, pbr=True, regions=pems.regions)
        assert {"main": cost.main_maps_bytes, "sharp": cost.sharp_maps_bytes, "targets": cost.targets_bytes,
                "pem": cost.pem_bytes} == got
        bound = frame_cost(settings, pem, quality["face_size"], casters, pbr=True)
        assert bound.least_shadow_bytes <= cost.shadow_bytes <= bound.shadow_bytes
    finally:
        pems.release()
        scene.release()
