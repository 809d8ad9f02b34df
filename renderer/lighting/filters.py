"""The 5x5 low-pass filters applied after each 2x2 MIP reduction (Knuth et al. 2014, section 3.2, Fig. 2).

Each filter is separable: the 2D kernel is the outer product of a normalized 1D kernel of 5 taps.
Cosine-based kernels sample the cosine at [-60, -30, 0, 30, 60] degrees, raised to a power, and are
divided by their sum (section 4); sqrt-cosine is the paper's choice. Normalized kernels add no
energy, so the MIP chain stays physically plausible.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from ..errors import InvalidInputError


class Filter(str, Enum):
    NONE = "none"
    BOX = "box"
    GAUSS = "gauss"
    COSINE = "cosine"
    SQRT_COSINE = "sqrt-cosine"

    @classmethod
    def parse(cls, value: Filter | str) -> Filter:
        try:
            return cls(value)
        except ValueError:
            raise InvalidInputError(
                f"unknown filter {value!r}; choose one of {', '.join(f.value for f in cls)}") from None


# Standard deviation of the Gaussian filter in texels of the level being filtered.
GAUSS_SIGMA_TEXELS = 1.0


def taps_1d(kind: Filter | str) -> np.ndarray:
    """The normalized 1D kernel (5,) float64 of a filter."""
    kind = Filter.parse(kind)
    x = np.arange(-2, 3, dtype=np.float64)
    if kind is Filter.NONE:
        w = (x == 0).astype(np.float64)
    elif kind is Filter.BOX:
        w = np.ones(5)
    elif kind is Filter.GAUSS:
        w = np.exp(-0.5 * (x / GAUSS_SIGMA_TEXELS) ** 2)
    else:
        c = np.cos(np.radians(30.0 * x))  # cos(-60), cos(-30), cos(0), cos(30), cos(60)
        w = c if kind is Filter.COSINE else np.sqrt(c)
    return w / w.sum()
