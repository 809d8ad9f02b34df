"""Error metrics of a rendered image against the Monte Carlo reference, both linear HDR RGB.

relative RMSE: the relative MSE of the Monte Carlo denoising literature (Rousselle, Knaus & Zwicker
2011, "Adaptive sampling and reconstruction using greedy error minimization"; Bako et al. 2017 use
the same with eps = 0.01), per pixel and per RGB channel

    relMSE = mean over covered pixels and the 3 channels of (t - r)^2 / (r^2 + eps),   eps = 0.01,

evaluated after dividing both images by the mean reference radiance over the mask (all channels).
HDR environment maps come in arbitrary radiance units; the normalization makes the metric invariant
to them, so the eps of the literature (stated for images of mean ~1) keeps its meaning: it stops
near-black pixels from dominating. We report its square root (a relative error: 0.05 = 5 %).

FLIP: NVIDIA's HDR-FLIP (Andersson et al. 2021), `flip_evaluator.evaluate(reference, test, "HDR")`,
default 67 pixels per degree; it tone-maps both images at several exposures chosen from the reference.
Pixels outside the mask are copied from the reference into the test image first, so only
differences on the object count, and the error map is averaged over the mask.

Artefact share: the share of judged object pixels whose luminance is more than 2x or less than 0.5x
the truth's. Both averages above spread a light leak or a blotch of false shadow over the whole
object; this counts them. Ratios are taken with a floor d = 2 % of the truth's mean luminance over
the object added to both sides, (Y_test + d) / (Y_truth + d): where the truth is dark a ratio means
nothing until the difference itself is visible, and a leak of 3 % of the mean into a black fold
(ratio 2.5 against a black truth) still counts. A pixel is judged only where the reference's own
noise is small: its two independent renders agree within 1.25x (the same floored ratio), so that
noise in the truth is never counted as an artefact of the fast method.

Window share: the same count over the object's 5 x 5 windows (every position, wholly inside the object:
by default the pixels every stratum of the reference covers), each judged by its mean luminance, wrong
beyond 1.5x either way. A blotch or a band of false shadow a few pixels wide moves a window's mean
where the pixels' own noise does not, so the ratio can be tighter than the pixels' 2x; the floor d and
the agreement of the two references are the artefact share's, on the windows' means.

Silhouette error: at the edge pixels of a reference that integrates the pixel's area
(`ReferenceFrame.edge`: pixels whose strata do not all see one surface), the relative RMSE above of the
test's premultiplied RGB against the reference's foreground (both over black: a frame rendered with a
black background is that; the normalization is over the edge pixels), and the RMSE of the coverage
alpha there. A renderer that shades pixel centres is off there by the part of the pixel it misses or
adds; one that anti-aliases by how well its coverage and its colour there follow the area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError

REL_MSE_EPS = 0.01
# Artefact share (module doc): a pixel is visibly wrong beyond this luminance ratio either way...
ARTEFACT_RATIO = 2.0
# ...with this share of the truth's mean luminance over the object added to both sides...
ARTEFACT_DARK_FLOOR = 0.02
# ...and judged only where the reference's two renders agree within this ratio.
ARTEFACT_AGREEMENT = 1.25
# Window share (module doc): windows of this side, wrong beyond this ratio of their mean luminance.
WINDOW_SIDE = 5
WINDOW_RATIO = 1.5
# A pixel is inside the object for the window share where the reference's alpha is at least this: every
# stratum hit (alpha is a share of the strata, 1 exactly when all hit; 0 or 1 without strata).
FULL_COVERAGE = 1.0 - 1e-6
# Rec. ITU-R BT.709 luminance weights (linear RGB).
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])


def _rgb_pair(test, ref, mask) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated float64 (H, W, 3) images and a bool (H, W) mask (default: reference alpha > 0.5, or all)."""
    t, r = np.asarray(test), np.asarray(ref)
    if t.ndim != 3 or r.ndim != 3 or t.shape[:2] != r.shape[:2] or t.shape[2] < 3 or r.shape[2] < 3:
        raise InvalidInputError(f"images must be (H, W, 3 or 4) of the same size; got {t.shape} and {r.shape}")
    if mask is None:
        mask = r[..., 3] > 0.5 if r.shape[2] >= 4 else np.ones(r.shape[:2], bool)
    mask = np.asarray(mask, bool)
    if mask.shape != r.shape[:2]:
        raise InvalidInputError(f"mask must have shape {r.shape[:2]}; got {mask.shape}")
    t, r = t[..., :3].astype(np.float64), r[..., :3].astype(np.float64)
    if not (np.all(np.isfinite(t[mask])) and np.all(np.isfinite(r[mask]))):
        raise InvalidInputError("images have NaN or Inf inside the mask")
    return t, r, mask


def relative_rmse(test: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None,
                  eps: float = REL_MSE_EPS) -> float:
    """sqrt(relMSE) of test against ref over the mask (see the module doc). test, ref: (H, W, 3 or 4)
    linear RGB; mask: bool (H, W), default the reference's alpha > 0.5. NaN when the mask is empty."""
    per_pixel = relative_squared_errors(test, ref, mask, eps)
    return float(np.sqrt(per_pixel.mean())) if per_pixel.size else float("nan")


def relative_squared_errors(test: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None,
                            eps: float = REL_MSE_EPS) -> np.ndarray:
    """Each covered pixel's share of relMSE: (t - r)^2 / (r^2 + eps) averaged over its 3 channels,
    after the normalization of the module doc; float64 (mask.sum(),), in the mask's row-major order.
    Its mean is relMSE: where in the image the error sits."""
    t, r, mask = _rgb_pair(test, ref, mask)
    if not mask.any():
        return np.zeros(0)
    t, r = t[mask], r[mask]
    scale = r.mean()
    if scale <= 0:
        scale = 1.0  # a black reference: plain relMSE in the map's units
    t, r = t / scale, r / scale
    return np.mean((t - r) ** 2 / (r * r + eps), axis=1)


def mean_flip(test: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean HDR-FLIP error of test against ref over the mask (see the module doc). NaN when the mask is empty."""
    import flip_evaluator

    t, r, mask = _rgb_pair(test, ref, mask)
    if not mask.any():
        return float("nan")
    t = np.where(mask[..., None], t, r)
    # HDR-FLIP needs non-negative input; negative radiance only arises from a bug upstream.
    t = np.ascontiguousarray(np.maximum(t, 0.0), np.float32)
    r = np.ascontiguousarray(np.maximum(r, 0.0), np.float32)
    error_map, _, _ = flip_evaluator.evaluate(r, t, "HDR", applyMagma=False)
    return float(np.asarray(error_map).reshape(mask.shape)[mask].mean())


@dataclass(frozen=True)
class NoiseFloor:
    """The metrics between two independent reference renders: what a perfect renderer would score."""

    relative_rmse: float
    mean_flip: float


def noise_floor(ref_a, ref_b, mask: np.ndarray | None = None) -> NoiseFloor:
    """The metrics of ref_b against ref_a (two renders with different seeds; `ReferenceFrame`s or
    (H, W, 4) images). The error of a single reference against the truth is about this / sqrt(2)."""
    a = getattr(ref_a, "image", ref_a)
    b = getattr(ref_b, "image", ref_b)
    return NoiseFloor(relative_rmse(b, a, mask), mean_flip(b, a, mask))


@dataclass(frozen=True)
class ArtefactShare:
    """Visibly wrong pixels (module doc). share: wrong / judged pixels (NaN when none is judged);
    judged: judged / object pixels; too_bright, too_dark: the wrong pixels by side."""

    share: float
    judged: float
    too_bright: int
    too_dark: int
    judged_pixels: int

    def as_dict(self) -> dict:
        return {"share": self.share, "judged": self.judged, "too_bright": self.too_bright,
                "too_dark": self.too_dark, "judged_pixels": self.judged_pixels}


def artefact_share(test: np.ndarray, ref_a: np.ndarray, ref_b: np.ndarray | None = None,
                   mask: np.ndarray | None = None) -> ArtefactShare:
    """The artefact share of test against the truth, the mean of two independent reference renders
    ref_a and ref_b (see the module doc); with ref_b None the truth is ref_a and every object pixel
    is judged. Images (H, W, 3 or 4) linear RGB; mask default: ref_a's alpha > 0.5."""
    t, a, mask = _rgb_pair(test, ref_a, mask)
    b = a if ref_b is None else _rgb_pair(ref_b, ref_a, mask)[0]
    y_t, y_a, y_b = (np.maximum(x[mask] @ LUMINANCE_RGB, 0.0) for x in (t, a, b))
    if not y_a.size:
        return ArtefactShare(float("nan"), float("nan"), 0, 0, 0)
    return _judge(y_t, y_a, y_b, _dark_floor(y_a, y_b), ARTEFACT_RATIO)


def _dark_floor(y_a: np.ndarray, y_b: np.ndarray) -> float:
    """d of the module doc: ARTEFACT_DARK_FLOOR x the truth's mean luminance over the object's pixels."""
    floor = ARTEFACT_DARK_FLOOR * float((0.5 * (y_a + y_b)).mean())
    return floor if floor > 0 else 1e-30   # a black truth: any light at all is a leak


def _judge(y_t: np.ndarray, y_a: np.ndarray, y_b: np.ndarray, floor: float, ratio: float) -> ArtefactShare:
    """Luminances (N,) of the test and of the two references, judged (module doc): where the references
    agree within ARTEFACT_AGREEMENT, wrong beyond `ratio` either way of their mean (floored ratios)."""
    truth = 0.5 * (y_a + y_b)
    judged = np.abs(np.log((y_a + floor) / (y_b + floor))) <= np.log(ARTEFACT_AGREEMENT)
    r = (y_t + floor) / (truth + floor)
    bright = judged & (r > ratio)
    dark = judged & (r < 1.0 / ratio)
    n = int(judged.sum())
    share = float((bright.sum() + dark.sum()) / n) if n else float("nan")
    return ArtefactShare(share, n / y_a.size if y_a.size else float("nan"), int(bright.sum()), int(dark.sum()), n)


def window_share(test: np.ndarray, ref_a: np.ndarray, ref_b: np.ndarray | None = None,
                 mask: np.ndarray | None = None, side: int = WINDOW_SIDE,
                 ratio: float = WINDOW_RATIO) -> ArtefactShare:
    """The share of the object's side x side windows whose mean luminance is off by more than `ratio`
    either way from the truth's (module doc), the truth the mean of ref_a and ref_b (or ref_a alone,
    every window judged). Images (H, W, 3 or 4) linear RGB; mask: bool (H, W), default the pixels that
    ref_a (and ref_b) cover wholly (alpha >= FULL_COVERAGE; alpha > 0.5 of 3-channel images: all). Every
    window position wholly inside the mask counts once; the result's counts are windows (judged: judged
    windows / windows inside; NaN share when none is judged)."""
    if mask is None:
        refs = [np.asarray(r) for r in (ref_a, ref_b) if r is not None]
        if all(r.ndim == 3 and r.shape[2] >= 4 for r in refs):
            mask = np.logical_and.reduce([r[..., 3] >= FULL_COVERAGE for r in refs])
    t, a, mask = _rgb_pair(test, ref_a, mask)
    b = a if ref_b is None else _rgb_pair(ref_b, ref_a, mask)[0]
    if isinstance(side, bool) or not isinstance(side, (int, np.integer)) or side < 1:
        raise InvalidInputError(f"the window's side must be a positive integer; got {side!r}")
    if not ratio > 1.0:
        raise InvalidInputError(f"the window's ratio must be > 1; got {ratio!r}")
    y_t, y_a, y_b = (np.where(mask, np.maximum(x @ LUMINANCE_RGB, 0.0), 0.0) for x in (t, a, b))
    if not mask.any():
        return ArtefactShare(float("nan"), float("nan"), 0, 0, 0)
    inside = _window_sums(mask.astype(np.int64), side) == side * side
    means = [_window_sums(y, side)[inside] / (side * side) for y in (y_t, y_a, y_b)]
    if not means[0].size:
        return ArtefactShare(float("nan"), float("nan"), 0, 0, 0)
    return _judge(*means, _dark_floor(y_a[mask], y_b[mask]), ratio)


def _window_sums(x: np.ndarray, side: int) -> np.ndarray:
    """Sums of x (H, W) over every side x side window, (H - side + 1, W - side + 1) (empty when the
    image is smaller), from the summed-area table (Crow 1984)."""
    h, w = x.shape
    if h < side or w < side:
        return np.zeros((0, 0), x.dtype)
    c = np.zeros((h + 1, w + 1), x.dtype)
    c[1:, 1:] = x.cumsum(axis=0).cumsum(axis=1)
    return c[side:, side:] - c[:-side, side:] - c[side:, :-side] + c[:-side, :-side]


@dataclass(frozen=True)
class SilhouetteError:
    """The silhouette error (module doc): rel_rmse of the premultiplied RGB and coverage_rmse of alpha
    over the `pixels` edge pixels (both NaN when there are none)."""

    rel_rmse: float
    coverage_rmse: float
    pixels: int

    def as_dict(self) -> dict:
        return {"rel_rmse": self.rel_rmse, "coverage_rmse": self.coverage_rmse, "pixels": self.pixels}


def silhouette_error(test: np.ndarray, ref_foreground: np.ndarray, edge: np.ndarray) -> SilhouetteError:
    """The silhouette error of test against the reference (module doc). test: (H, W, 4) a frame over a
    black background (premultiplied linear RGB, coverage alpha); ref_foreground: (H, W, 4) the
    reference's `foreground`; edge: bool (H, W), the reference's `edge` mask."""
    t, r = np.asarray(test), np.asarray(ref_foreground)
    if t.ndim != 3 or r.ndim != 3 or t.shape[2] < 4 or r.shape[2] < 4:
        raise InvalidInputError(f"the silhouette error needs (H, W, 4) images with alpha; got {t.shape} and {r.shape}")
    edge = np.asarray(edge, bool)
    n = int(edge.sum()) if edge.shape == r.shape[:2] else 0
    rel = relative_rmse(t, r, edge)   # validates the sizes and the mask
    if not n:
        return SilhouetteError(float("nan"), float("nan"), 0)
    da = t[..., 3][edge].astype(np.float64) - r[..., 3][edge].astype(np.float64)
    if not np.all(np.isfinite(da)):
        raise InvalidInputError("alpha has NaN or Inf at the edge pixels")
    return SilhouetteError(rel, float(np.sqrt(np.mean(da * da))), n)
