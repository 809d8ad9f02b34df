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
    truth = 0.5 * (y_a + y_b)
    floor = ARTEFACT_DARK_FLOOR * float(truth.mean())
    if floor <= 0:
        floor = 1e-30   # a black truth: any light at all is a leak
    judged = np.abs(np.log((y_a + floor) / (y_b + floor))) <= np.log(ARTEFACT_AGREEMENT)
    ratio = (y_t + floor) / (truth + floor)
    bright = judged & (ratio > ARTEFACT_RATIO)
    dark = judged & (ratio < 1.0 / ARTEFACT_RATIO)
    n = int(judged.sum())
    share = float((bright.sum() + dark.sum()) / n) if n else float("nan")
    return ArtefactShare(share, n / y_a.size, int(bright.sum()), int(dark.sum()), n)
