"""The pixel's area in the Monte Carlo reference (numpy only): its strata and their jittered positions,
how the shading samples are split and stratified over them, and the edge test. montecarlo.py's module
doc states the estimator these serve; the reasons live here.

Pixel (row, col) is the square [col, col + 1) x [row, row + 1) in pixel units (x to the right from the
image's left edge, y down from its top edge). With k = pixel_samples it has k x k strata, stratum
s = i k + j the square [col + j / k, col + (j + 1) / k) x [row + i / k, row + (i + 1) / k), each seen
through one position jittered uniformly within it (Cook 1986, "Stochastic sampling in computer
graphics"; Pharr, Jakob & Humphreys, PBRT 3rd ed., sec. 7.3). k = 1 is the pixel's centre, not jittered:
the point sample the reference took before it integrated the area.

Why one position per stratum, shaded with many samples, estimates the box-filtered pixel without
bias: the pixel is I = integral over its square of c(p) dp, c(p) the radiance seen through position p
(the shaded surface, or the environment along a ray that misses; 0 for a miss in the foreground). A
position p_s uniform in stratum s (area 1 / k^2) has E[c(p_s)] = k^2 * integral over stratum s of c, so
E[(1 / k^2) sum_s c(p_s)] = I. The shading estimate at p_s is unbiased given p_s
(E[c_hat(p_s) | p_s] = c(p_s)), so E[(1 / k^2) sum_s c_hat(p_s)] = I by the tower property. What the
shading samples cannot remove is the area's own sampling error: one render's positions are fixed, so
its image carries the error of a k^2-point stratified estimate of I. Where c is smooth over the pixel
that error is second order; where an edge crosses it, only the ~k strata the edge crosses are
uncertain, each by at most its area 1 / k^2, so a pixel's coverage is within (strata crossed) / k^2 of
the truth (at most (2k - 1) / k^2) and off by about 0.4 k^(-3/2) rms (0.05 at k = 4, measured over
random straight edges). It does not fall with spp and is not in noise_std; two renders with other
seeds jitter independently, so the noise floor between them holds it.

Shading samples: spp is per pixel, as at k = 1: split evenly over the strata, rounded up, and at least
min(batches, spp) each, so that every batch holds a sample of every stratum (`sample_counts`). Below
k^2 * batches samples a pixel therefore takes k^2 * min(batches, spp): more than asked, and the frame's
spp says how many. Cost: the same shadow rays as k = 1 at the same spp per pixel, plus k^2 primary rays
and surface evaluations per pixel.

The strata share one stratification of the sample dimensions. Within a batch of n_b samples a stratum
alone would stratify its texel and lobe numbers over its own n_b = spp / (k^2 B) samples (2 at spp 256,
k = 4, B = 8), which removes little of the variance the stratification removes at k = 1 (montecarlo.py's
module doc: 4.7 % -> 2.6 % noise at 256 spp). So the pixel's k^2 n_b samples of a batch stratify
[0, 1) together, k^2 n_b slots: stratum s takes the n_b slots of block sigma_b(s), sigma_b a uniformly
random permutation of the strata drawn per pixel and batch (`stratum_slots`). Each stratum's block is
uniform over the blocks, so each stratum's batch mean stays unbiased whatever the others hit (misses
leave their blocks unused), and the permutations of different batches are independent, so the batches
stay independent and the error estimate honest. A stratum's own batch means are not independent of
its neighbours': only the pixel's (the mean over its strata) are, and its noise comes from those.
Measured at the same spp a pixel: k = 4 is as noisy as the centre (polo, satin, 128 x 128, 128 spp:
5.16 % against 5.11 %; 2.08 M rays against 1.83 M, the 16 primary rays a pixel, in 3.3 s against 3.0 s
on one thread), where strata stratified each on their own triple the noise (tests' sphere and plane
under a sun, 256 spp: 3.1 % against 1.1 %).

Edges (`EdgeTest`): a pixel is an edge where its strata do not all see one surface: some hit and some
miss, or they hit different meshes, or two hits lie off each other's triangle plane by more than
EDGE_FOOTPRINTS pixel footprints (a footprint: a pixel's side on a plane facing the camera at the hit's
view depth). The plane test finds a sleeve over the torso, or a fold's near layer over its far one,
where a depth test would also flag a smooth surface seen at a grazing angle (its depth changes by a
footprint / tan of the angle across one pixel) and a crease (two triangles at an angle, sharing an
edge: off each other's plane by less than a footprint times the sine of the angle) would pass.
"""

from __future__ import annotations

import numpy as np

# k x k strata at most: a stratum's slot block fits a uint8 (k^2 <= 256).
MAX_PIXEL_SAMPLES = 16
# Two hits of one pixel off each other's triangle plane by more than this many pixel footprints are
# two surfaces (module doc): garment layers are a few millimetres to centimetres apart, a footprint
# ~4 mm at 256 x 256 over a 1 m frame; a curved surface strays from its tangent plane across one
# pixel by far less than a footprint.
EDGE_FOOTPRINTS = 3.0
# Tags that keep the strata's random streams apart from the shading samples' (whose seeds have 4 or 6
# words: (seed, batch, first sample, first point) and, with strata, (strata, stratum)).
_JITTER_STREAM = 0x6A69_7474   # "jitt"
_SLOT_STREAM = 0x736C_6F74     # "slot"


def sample_counts(spp: int, pixel_samples: int, batches: int) -> tuple[int, int]:
    """(samples per stratum, batches) for `spp` samples per pixel over pixel_samples^2 strata (module
    doc): spp / k^2 rounded up, at least min(batches, spp) so every batch holds every stratum."""
    batches = min(batches, spp)
    return max(-(-spp // pixel_samples ** 2), batches), batches


def stratum_positions(width: int, height: int, pixel_samples: int, stratum: int, seed: int) -> np.ndarray:
    """The position of `stratum` in every pixel, float64 (H * W, 2) (x, y) in pixel units, row-major
    from the top row: jittered within the stratum by a stream of (seed, pixel_samples, stratum); the
    pixel's centre when pixel_samples is 1."""
    k = pixel_samples
    i, j = divmod(stratum, k)
    row, col = np.divmod(np.arange(height * width), width)
    if k == 1:
        return np.stack([col + 0.5, row + 0.5], axis=1)
    u = np.random.default_rng([seed, _JITTER_STREAM, k, stratum]).random((height * width, 2))
    return np.stack([col + (j + u[:, 0]) / k, row + (i + u[:, 1]) / k], axis=1)


def stratum_slots(seed: int, batches: int, n_pixels: int, strata: int) -> np.ndarray:
    """sigma_b(s) of the module doc: uint8 (B, n_pixels, strata), per batch and pixel a uniformly random
    permutation of the strata (the argsort of independent uniforms), each batch from its own stream."""
    out = np.empty((batches, n_pixels, strata), np.uint8)
    for b in range(batches):
        u = np.random.default_rng([seed, _SLOT_STREAM, strata, b]).random((n_pixels, strata))
        out[b] = np.argsort(u, axis=1)
    return out


class EdgeTest:
    """Accumulates, stratum by stratum, whether each pixel's strata see one surface (module doc).

    pitch: a pixel's side on a plane facing the camera at unit view depth (2 tan(fov_y / 2) / height);
    eye, forward: the camera's position and unit viewing direction (view depth = (x - eye).forward)."""

    def __init__(self, n_pixels: int, pitch: float, eye: np.ndarray, forward: np.ndarray):
        self.pitch, self.eye, self.forward = pitch, np.asarray(eye, np.float64), np.asarray(forward, np.float64)
        self.mesh = np.full(n_pixels, -1, np.int64)     # the first hit's mesh (-1: no hit yet)
        self.x = np.zeros((n_pixels, 3))                 # ... its point
        self.n = np.zeros((n_pixels, 3))                 # ... its triangle's unit normal
        self.hits = np.zeros(n_pixels, np.int64)        # strata that hit
        self.off = np.zeros(n_pixels, bool)             # two hits on different surfaces

    def add(self, pixels: np.ndarray, mesh: np.ndarray, x: np.ndarray, n_geom: np.ndarray) -> None:
        """One stratum's hits: pixel indices (M,), their mesh (M,), points (M, 3), triangle normals (M, 3)."""
        self.hits[pixels] += 1
        first = self.mesh[pixels] < 0
        p = pixels[first]
        self.mesh[p], self.x[p], self.n[p] = mesh[first], x[first], n_geom[first]
        rest = ~first
        p = pixels[rest]
        d = x[rest] - self.x[p]
        apart = np.maximum(np.abs(np.einsum("ij,ij->i", d, self.n[p])), np.abs(np.einsum("ij,ij->i", d, n_geom[rest])))
        depth = np.maximum((self.x[p] - self.eye) @ self.forward, 0.0)
        self.off[p] |= (mesh[rest] != self.mesh[p]) | (apart > EDGE_FOOTPRINTS * self.pitch * depth)

    def edges(self, strata: int) -> np.ndarray:
        """bool (n_pixels,): some strata hit and some miss, or the hits are on different surfaces."""
        return self.off | ((self.hits > 0) & (self.hits < strata))
