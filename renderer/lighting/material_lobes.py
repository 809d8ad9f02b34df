"""The lobe tables of the physically based materials: Kautz and McCool's fit (lobe_fit.py) of every
roughness and view elevation, made once, stored, and read by the shader (shaders/shading/lobes.glsl)
as the paper's third dimension, view elevation, plus one for roughness, so that roughness may vary
per vertex.

Two models (renderer/shading/brdf.py), each fitted with its colour factored out:

- "ggx", glTF's metallic-roughness specular. Schlick's Fresnel is linear in F0, so the slice is
  F0 A(l) + B(l) with A = D V (1 - (1 - v.h)^5) (n.l) and B = D V (1 - v.h)^5 (n.l) (Karis's split
  sum). The lobes are fitted to A + B (F0 = 1, a white metal) and carry, per pixel, the energy
  F0 a + b, a and b the integrals of A and B over the hemisphere. The diffuse part,
  (1 - F(v.h)) (1 - metallic) base / pi (n.l), integrates to (1 - F0) (1 - metallic) base c with
  c the integral of (1 - (1 - v.h)^5) (n.l) / pi: the renderer's diffuse term (a lookup along n at
  the cosine level) times that weight.
- "sheen", KHR_materials_sheen's Charlie layer with colour 1: its lobes and its directional albedo
  E, which also scales the layer below (the extension's albedo scaling, 1 - max(sheen colour) E(n.v)).

Each cell stores, per lobe, its weight relative to the slice's reflectivity (the lobes' parts above
the horizon sum to 1: the shader clips them there, lighting.frag), 1 / s (s the lobe's exponent; the shader maps
it to a PEM level through the same calibration as a Phong g = 1 - 1 / s) and its angle psi from the
normal towards the view (lobe_fit.axis_at). Grids: roughness and view elevation, both uniform;
lookups between nodes are bilinear, below the first roughness node clamped to it.

Made by `python -m renderer.lighting.material_lobes --store` (a few minutes on two cores); a test
fits cells again and compares.
"""

from __future__ import annotations

import argparse
import functools
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..shading import brdf
from .lobe_fit import N, fit_lobes, judge_grid, view_direction

MODELS = ("ggx", "sheen")
MAX_LOBES = 2
ROUGHNESS = np.linspace(0.05, 1.0, 12)
THETA_V = np.radians(np.linspace(0.0, 88.0, 12))
TABLE_PATH = Path(__file__).resolve().parent.parent / "data" / "material_lobes.npz"
# Floats per cell in the shader's table: three scalars (ggx: a, b, c; sheen: E, 0, 0), then per lobe
# (weight relative to the reflectivity, 1 / s, psi).
SCALARS = 3


def ggx_scalars(roughness: float, theta_v: float) -> tuple[float, float, float]:
    """(a, b, c) of the module doc at one roughness and view elevation, on the fit's judge grid, from
    brdf.ggx itself: a white metal (F0 = 1) reflects a + b, a black one (F0 = 0, F = (1 - v.h)^5) b,
    and a white dielectric's diffuse part (less its specular, a black dielectric's) is (1 - 0.04) c."""
    v = view_direction(theta_v)
    grid = judge_grid(theta_v)
    cell = np.broadcast_to(grid.d_omega, grid.dirs.shape[:-1])

    def reflected(base: float, metallic: float) -> float:
        return float(np.sum(brdf.ggx(N, v, grid.dirs, base, metallic, roughness)[..., 0] * cell))

    b = reflected(0.0, 1.0)
    return (reflected(1.0, 1.0) - b, b,
            (reflected(1.0, 0.0) - reflected(0.0, 0.0)) / (1.0 - brdf.DIELECTRIC_F0))


def fit_cell(model: str, roughness: float, theta_v: float, count: int):
    """The fit of one cell (lobe_fit.Fit): the colourless slice of `model`."""
    if model == "ggx":
        return fit_lobes(brdf.ggx, theta_v, count, base=1.0, metallic=1.0, roughness=roughness)
    if model == "sheen":
        return fit_lobes(brdf.sheen, theta_v, count, colour=1.0, roughness=roughness)
    raise ValueError(f"model must be one of {MODELS}, got {model!r}")


def _cell(job):
    model, i, j, count = job
    fit = fit_cell(model, float(ROUGHNESS[i]), float(THETA_V[j]), count)
    lobes = np.zeros((count, 3))
    for k, lobe in enumerate(fit.lobes):
        # Relative to the reflectivity: the lobes' parts above the horizon sum to 1 (the energy
        # correction); a lobe that reaches below it weighs more, and the shader clips it there.
        lobes[k] = (lobe.weight / fit.reflectivity if fit.reflectivity > 0 else 0.0, 1.0 / lobe.exponent,
                    np.arctan2(lobe.axis[0], lobe.axis[2]))
    scalars = ggx_scalars(float(ROUGHNESS[i]), float(THETA_V[j])) if model == "ggx" else (fit.reflectivity, 0.0, 0.0)
    return job, lobes, np.array(scalars), fit.rel_rms, fit.greedy_rel_rms


@dataclass(frozen=True)
class LobeTables:
    """arrays["{model}_{count}_lobes"] (R, J, count, 3): per lobe (weight / reflectivity, 1 / s, psi);
    arrays["{model}_{count}_scalars"] (R, J, 3); arrays["{model}_{count}_rms"] and "_greedy_rms"
    (R, J): the fit's relative RMS error after / before the joint refinement. roughness (R,),
    theta_v (J,): the nodes."""

    roughness: np.ndarray
    theta_v: np.ndarray
    arrays: dict

    def lobes(self, model: str, count: int) -> np.ndarray:
        return self.arrays[f"{model}_{count}_lobes"]

    def scalars(self, model: str, count: int) -> np.ndarray:
        return self.arrays[f"{model}_{count}_scalars"]

    def rms(self, model: str, count: int, greedy: bool = False) -> np.ndarray:
        return self.arrays[f"{model}_{count}_{'greedy_rms' if greedy else 'rms'}"]

    def packed(self, model: str, count: int) -> np.ndarray:
        """The shader's table: float32 (R * J * (SCALARS + 3 count),), roughness-major."""
        cells = np.concatenate([self.scalars(model, count), self.lobes(model, count).reshape(
            len(self.roughness), len(self.theta_v), -1)], axis=-1)
        return np.ascontiguousarray(cells, np.float32).ravel()

    def interpolate(self, model: str, count: int, roughness, n_v) -> tuple[np.ndarray, np.ndarray]:
        """(scalars (..., 3), lobes (..., count, 3)) at roughness and n.v, bilinear as the shader
        reads them (the reference's sheen albedo scaling uses the same E)."""
        x = np.clip((np.asarray(roughness, np.float64) - self.roughness[0]) / (self.roughness[1] - self.roughness[0]),
                    0.0, len(self.roughness) - 1)
        theta = np.arccos(np.clip(np.asarray(n_v, np.float64), 0.0, 1.0))
        y = np.clip(theta / (self.theta_v[1] - self.theta_v[0]), 0.0, len(self.theta_v) - 1)
        i0 = np.minimum(np.floor(x).astype(int), len(self.roughness) - 2)
        j0 = np.minimum(np.floor(y).astype(int), len(self.theta_v) - 2)
        fx, fy = x - i0, y - j0
        out = []
        for table in (self.scalars(model, count), self.lobes(model, count)):
            extra = (None,) * (table.ndim - 2)
            wx, wy = fx[(...,) + extra], fy[(...,) + extra]
            out.append((1 - wx) * (1 - wy) * table[i0, j0] + wx * (1 - wy) * table[i0 + 1, j0]
                       + (1 - wx) * wy * table[i0, j0 + 1] + wx * wy * table[i0 + 1, j0 + 1])
        return out[0], out[1]

    def sheen_albedo(self, roughness, n_v) -> np.ndarray:
        """E(n.v) of the Charlie layer with colour 1 (..,)."""
        return self.interpolate("sheen", MAX_LOBES, roughness, n_v)[0][..., 0]


def build(workers: int = 2) -> LobeTables:
    jobs = [(m, i, j, c) for m in MODELS for c in range(1, MAX_LOBES + 1)
            for i in range(len(ROUGHNESS)) for j in range(len(THETA_V))]
    shape = (len(ROUGHNESS), len(THETA_V))
    arrays = {}
    for m in MODELS:
        for c in range(1, MAX_LOBES + 1):
            arrays[f"{m}_{c}_lobes"] = np.zeros(shape + (c, 3))
            arrays[f"{m}_{c}_scalars"] = np.zeros(shape + (SCALARS,))
            arrays[f"{m}_{c}_rms"] = np.zeros(shape)
            arrays[f"{m}_{c}_greedy_rms"] = np.zeros(shape)
    with ProcessPoolExecutor(workers) as pool:
        for (m, i, j, c), lobes, scalars, rms, greedy in pool.map(_cell, jobs, chunksize=4):
            arrays[f"{m}_{c}_lobes"][i, j] = lobes
            arrays[f"{m}_{c}_scalars"][i, j] = scalars
            arrays[f"{m}_{c}_rms"][i, j] = rms
            arrays[f"{m}_{c}_greedy_rms"][i, j] = greedy
    return LobeTables(ROUGHNESS.copy(), THETA_V.copy(), arrays)


def store(tables: LobeTables, path: Path = TABLE_PATH) -> None:
    np.savez_compressed(path, roughness=tables.roughness, theta_v=tables.theta_v, **tables.arrays)


@functools.cache
def load(path: Path = TABLE_PATH) -> LobeTables:
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k not in ("roughness", "theta_v")}
        tables = LobeTables(data["roughness"], data["theta_v"], arrays)
    if not (np.allclose(tables.roughness, ROUGHNESS) and np.allclose(tables.theta_v, THETA_V)):
        raise RuntimeError(f"{path} was made on other nodes: run python -m renderer.lighting.material_lobes --store")
    return tables


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--store", action="store_true", help=f"write {TABLE_PATH.name} into renderer/data")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    tables = build(args.workers)
    for m in MODELS:
        for c in range(1, MAX_LOBES + 1):
            print(f"{m} {c} lobe(s): rel. RMS median {np.median(tables.rms(m, c)):.3f}, worst {tables.rms(m, c).max():.3f}")
    if args.store:
        store(tables)
        print(f"wrote {TABLE_PATH}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
