"""Coarser shadow casters (renderer/shadows/proxy.py): the same vertices, fewer triangles; the
shadow they cast stays where the full mesh's is, and follows the mesh when it moves. The shadow pass
draws front faces alone, over triangles turned to face outwards whatever the source's winding."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material
from renderer.shadows.proxy import caster_proxy, light_facing, shadow_faces


@pytest.mark.parametrize("keep", [0.5, 0.25, 0.1])
def test_proxy_keeps_the_share_of_triangles_over_the_original_vertices(keep):
    m = sphere(1.0, subdivisions=4)   # 5120 triangles
    f = caster_proxy(m.positions, m.faces, keep)
    assert f.dtype == np.int32 and f.shape[1] == 3
    assert abs(len(f) / len(m.faces) - keep) < 0.05, len(f)
    assert f.min() >= 0 and f.max() < len(m.positions)
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f)
    # The proxy is a closed surface near the sphere: every vertex of the original lies close to it.
    proxy = trimesh.Trimesh(m.positions, f, process=False)
    _, dist, _ = trimesh.proximity.closest_point(proxy, m.positions)
    edge = np.linalg.norm(m.positions[m.faces[:, 0]] - m.positions[m.faces[:, 1]], axis=1).mean()
    assert dist.max() < edge / keep ** 0.5, (dist.max(), edge)
    assert proxy.is_watertight


def test_full_detail_is_the_mesh_itself_and_bad_shares_are_refused():
    m = sphere(1.0, subdivisions=2)
    assert np.array_equal(caster_proxy(m.positions, m.faces, 1.0), m.faces)
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(InvalidInputError, match="caster_detail"):
            caster_proxy(m.positions, m.faces, bad)
        with pytest.raises(InvalidInputError, match="caster_detail"):
            FrameSettings(caster_detail=bad)


def test_a_proxy_casts_the_full_meshs_shadow_and_follows_it(renderer):
    sun = np.array([0.5, 1.0, 0.2])
    sun /= np.linalg.norm(sun)
    cube = sun_sky_cube(64, sun, sun_radiance=5e3, sun_radius_deg=2, sky=(0.05, 0.05, 0.05), ground=(0, 0, 0))
    ball = sphere(0.4, centre=(0.0, 0.8, 0.0), subdivisions=4)
    scene = renderer.create_scene([ball, plane(6.0)], [Material((0.5, 0.5, 0.5)), Material((0.8, 0.8, 0.8))])
    cam = Camera((0.0, 4.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=50.0)
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        def frame(detail, positions=None):
            fs = FrameSettings(96, 96, caster_detail=detail, background=Background.BLACK)
            return renderer.render(scene, pems, fs, cam, positions=positions)

        full, coarse = frame(1.0), frame(0.25)
        moved = frame(0.25, [ball.positions + np.float32([0.8, 0.0, 0.0]), None])
        moved_full = frame(1.0)
    finally:
        pems.release()
        scene.release()
    assert coarse.timings["shadow_triangles"] < 0.3 * full.timings["shadow_triangles"]
    lum = lambda f: f.image[..., :3].mean(axis=-1)  # noqa: E731
    # The same shadow: dark where the full mesh's shadow is, lit where it is lit.
    shadow = lum(full) < 0.3 * np.percentile(lum(full), 90)
    assert shadow.sum() > 50
    agree = (lum(coarse) < 0.3 * np.percentile(lum(coarse), 90)) == shadow
    assert agree.mean() > 0.98, agree.mean()
    rel = np.abs(lum(coarse) - lum(full)).sum() / lum(full).sum()
    assert rel < 0.03, rel
    # The proxy indexes the same vertex buffer: moving the mesh moves its shadow, as with full detail.
    assert np.abs(lum(moved) - lum(moved_full)).sum() / lum(moved_full).sum() < 0.03
    assert np.abs(lum(moved) - lum(coarse)).sum() / lum(coarse).sum() > 0.05


def test_proxies_made_in_advance_are_used_and_checked(renderer):
    from renderer.errors import MeshError

    ball = sphere(0.4, subdivisions=3)
    faces = shadow_faces(ball.positions, ball.faces, 0.5)
    pems = renderer.build_pems(sun_sky_cube(16, (0, 1, 0)), PEMSettings(6))
    with pytest.raises(MeshError, match="caster proxy"):
        renderer.create_scene([ball], [Material()], proxies={0.5: [faces + len(ball.positions)]})
    scene = renderer.create_scene([ball], [Material()], proxies={0.5: [faces]})
    try:
        f = renderer.render(scene, pems, FrameSettings(16, 16, caster_detail=0.5), Camera((0, 0, 3), (0, 0, 0)))
        assert f.timings["shadow_triangles"] == f.timings["shadow_layers"] * len(faces) > 0
    finally:
        scene.release()
        pems.release()


def test_a_large_proxy_is_made_in_a_child_process_with_the_same_result(monkeypatch):
    from renderer.shadows import proxy

    m = sphere(1.0, subdivisions=3)
    here = shadow_faces(m.positions, m.faces, 0.25)
    monkeypatch.setattr(proxy, "ISOLATE_ABOVE", 100)   # this mesh counts as large
    monkeypatch.setattr(proxy, "shadow_faces", lambda *a: pytest.fail("ran in this process"))
    # The child process imports the module afresh: it runs the real shadow_faces.
    assert np.array_equal(proxy.shadow_faces_isolated(m.positions, m.faces, 0.25), here)


def _outward(positions, faces, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Whether each triangle's winding normal points away from `centre`."""
    p = positions[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return np.einsum("ij,ij->i", n, p.mean(axis=1) - np.asarray(centre)) > 0


def _unordered(faces) -> list:
    return sorted(map(tuple, np.sort(faces, axis=1)))


def test_light_facing_turns_every_piece_outwards_and_draws_an_unclear_one_both_ways():
    ball = sphere(1.0, subdivisions=3)
    p, f = ball.positions, ball.faces
    assert _outward(p, f).all()
    assert np.array_equal(light_facing(p, f), f)                      # outward already: as it was
    inward = light_facing(p, f[:, ::-1])
    assert len(inward) == len(f) and _outward(p, inward).all()       # wound inwards: turned round
    # Half the ball wound the other way (a panel sewn on inside out): two open pieces, each turned.
    top = p[f].mean(axis=1)[:, 1] > 0
    mixed = np.where(top[:, None], f[:, ::-1], f)
    out = light_facing(p, mixed)
    assert len(out) == len(f) and _outward(p, out).all()
    assert _unordered(out) == _unordered(f)
    # A flat sheet has no outside: both ways, so that one of them faces any light.
    sheet = plane(2.0)
    both = light_facing(sheet.positions, sheet.faces)
    assert len(both) == 2 * len(sheet.faces)
    assert _unordered(both) == _unordered(np.concatenate([sheet.faces, sheet.faces]))
    assert set(map(tuple, both)) >= set(map(tuple, sheet.faces)) | set(map(tuple, sheet.faces[:, ::-1]))
    assert len(light_facing(p, f[:0])) == 0


def test_the_shadow_is_the_same_whichever_way_a_caster_is_wound(renderer):
    sun = np.array([0.3, 1.0, 0.2])
    sun /= np.linalg.norm(sun)
    cube = sun_sky_cube(32, sun, sun_radiance=5e3, sun_radius_deg=2, sky=(0.05, 0.05, 0.05), ground=(0, 0, 0))
    ball = sphere(0.4, centre=(-0.6, 0.8, 0.0), subdivisions=3)
    sheet = plane(0.8, y=0.6)
    sheet = sheet.with_positions(sheet.positions + np.float32([0.6, 0.0, 0.0]))
    cam = Camera((0.0, 4.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=50.0)
    pems = renderer.build_pems(cube, PEMSettings(12))
    fs = FrameSettings(96, 96, background=Background.BLACK)
    images = []
    try:
        for flip in (False, True):
            casters = [m if not flip else type(m).from_arrays(m.positions, m.faces[:, ::-1], name=m.name)
                       for m in (ball, sheet)]
            scene = renderer.create_scene([*casters, plane(6.0)], [Material((0.5, 0.5, 0.5))] * 3)
            try:
                images.append(renderer.render(scene, pems, fs, cam).image[..., :3].mean(axis=-1))
            finally:
                scene.release()
    finally:
        pems.release()
    # Both casters shadow the floor (a dark share of the frame), the same with either winding.
    assert (images[0] < 0.3 * np.percentile(images[0], 90)).mean() > 0.02
    assert np.abs(images[0] - images[1]).sum() / images[0].sum() < 0.01
