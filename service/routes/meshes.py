"""Mesh files (PLY/OBJ/GLB/glTF/STL) uploaded once, read by trimesh with the file's vertex order kept,
then referenced by `mesh_id` when a scene is registered. Same bytes + options give the same id."""

from __future__ import annotations

import hashlib
import warnings
from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, Depends, Query, Request, Response, status

from renderer.errors import InvalidInputError, MeshError
from renderer.mesh import load_mesh

from ..codecs import uploaded_file
from ..deps import OCTET_STREAM, MeshesDep, SettingsDep, media_type, raw_body, require_token
from ..errors import InvalidRequestError
from ..registry import MeshRecord
from ..schemas import MeshInfo
from ..specs import check_counts

router = APIRouter(prefix="/meshes", tags=["meshes"], dependencies=[Depends(require_token)])

_FORMAT_OF_MEDIA = {"model/obj": "obj", "text/plain": "obj", "application/ply": "ply", "model/ply": "ply",
                    "model/gltf-binary": "glb", "model/gltf+json": "gltf", "model/stl": "stl",
                    "application/sla": "stl", "model/x.stl-binary": "stl"}
MESH_MEDIA_TYPES = (OCTET_STREAM, *_FORMAT_OF_MEDIA)

MeshFormat = Literal["obj", "ply", "glb", "gltf", "stl"]


def mesh_info(rec: MeshRecord) -> MeshInfo:
    s = rec.mesh.stats()
    return MeshInfo(id=rec.id, name=rec.mesh.name, format=rec.format, n_vertices=s.n_vertices, n_faces=s.n_faces,
                    has_uvs=rec.mesh.uvs is not None, bounds=s.bounds, n_degenerate=s.n_degenerate,
                    n_unreferenced=s.n_unreferenced, material=_material_summary(rec))


def _material_summary(rec: MeshRecord) -> str | None:
    m = rec.material
    if m is None:
        return None
    maps = list(dict.fromkeys(name for ts in m.texture_groups() for name, x in (
        ("base colour", ts.albedo_map), ("metallic-roughness", ts.metallic_roughness_map), ("normal", ts.normal_map),
        ("sheen", ts.sheen_map)) if x is not None))
    if len(m.texture_groups()) > 1:
        maps.append(f"{len(m.texture_groups())} texture sets")
    def value(x) -> str:   # a scalar, or its range over the vertices (a file of several materials)
        a = np.asarray(x, np.float64)
        return f"{float(a):g}" if a.ndim == 0 else f"{a.min():g}-{a.max():g} per vertex"

    sheen = np.asarray(m.sheen_colour, np.float64)
    text = (f"pbr: metallic {value(m.metallic)}, roughness {value(m.roughness)}"
            + ((f", sheen {tuple(round(float(c), 4) for c in sheen)}" if sheen.ndim == 1 else ", sheen per vertex")
               if m.has_sheen() else "")
            + (f", textures: {', '.join(maps)}" if maps else ""))
    return text + (f" ({rec.material_notes})" if rec.material_notes else "")


def _load(data: bytes, fmt: str, up: str, scale: float, name: str):
    """(the mesh, a glTF file's own material or None, what of that material was not read)."""
    material, notes = None, None
    with uploaded_file(data, fmt, "mesh-") as path:
        try:
            mesh = load_mesh(path, up=up, scale=scale)
            if fmt in ("glb", "gltf"):
                from renderer.shading.gltf import material_from_gltf

                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    material = material_from_gltf(path)
                notes = "; ".join(str(w.message).replace(str(path), "the file") for w in caught) or None
        except (MeshError, InvalidInputError) as e:
            raise type(e)(str(e).replace(str(path), f"uploaded {fmt.upper()} {name!r}")) from None
    from renderer.mesh import Mesh

    return Mesh.from_arrays(mesh.positions, mesh.faces, mesh.uvs, name=name), material, notes


@router.post("", response_model=MeshInfo, status_code=status.HTTP_201_CREATED,
             openapi_extra={"requestBody": {"required": True, "content": {
                 OCTET_STREAM: {"schema": {"type": "string", "format": "binary"}}}}},
             summary="Upload a mesh file (vertex order kept) for POST /scenes {garment: {mesh_id}}")
async def upload_mesh(
    request: Request, settings: SettingsDep, meshes: MeshesDep,
    format: Annotated[MeshFormat | None, Query(description="file format; default from the Content-Type")] = None,
    up: Literal["y", "z"] = "y",
    scale: Annotated[float, Query(gt=0, description="multiplies positions (0.01 for centimetres)")] = 1.0,
    name: Annotated[str | None, Query(max_length=200)] = None,
) -> MeshInfo:
    data = await raw_body(request, MESH_MEDIA_TYPES, "a mesh file")
    fmt = format or _FORMAT_OF_MEDIA.get(media_type(request))
    if fmt is None:
        raise InvalidRequestError("say the mesh file's format with ?format=obj|ply|glb|gltf|stl "
                                  "(or a model/* Content-Type)")
    digest = hashlib.sha256(data + f"|{fmt}|{up}|{scale!r}".encode()).hexdigest()
    label = name or f"mesh-{digest[:8]}"
    mesh, material, notes = await anyio.to_thread.run_sync(_load, data, fmt, up, scale, label)
    check_counts(mesh.n_vertices, mesh.n_faces, label, settings)
    rec = meshes.add(MeshRecord(id="msh_" + digest[:16], mesh=mesh, file_sha256=digest, format=fmt, up=up,
                                scale=scale, material=material, material_notes=notes))
    return await anyio.to_thread.run_sync(mesh_info, rec)


@router.get("", response_model=list[MeshInfo], summary="List uploaded mesh files")
async def list_meshes(meshes: MeshesDep) -> list[MeshInfo]:
    return [mesh_info(r) for r in meshes.list()]


@router.get("/{mesh_id}", response_model=MeshInfo)
async def get_mesh(mesh_id: str, meshes: MeshesDep) -> MeshInfo:
    return mesh_info(meshes.get(mesh_id))


@router.delete("/{mesh_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response)
async def delete_mesh(mesh_id: str, meshes: MeshesDep) -> Response:
    meshes.remove(mesh_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
