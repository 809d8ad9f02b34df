"""The Monte Carlo ground truth (embree ray casting) and the error metrics measured against it."""

from .envsampling import EnvironmentSampler
from .metrics import (
           ArtefactShare,
           NoiseFloor,
           SilhouetteError,
           artefact_share,
           mean_flip,
           noise_floor,
           relative_rmse,
           relative_squared_errors,
           silhouette_error,
           window_share,
)
from .montecarlo import ReferenceFrame, primary_rays, render_reference

__all__ = ["ArtefactShare", "EnvironmentSampler", "artefact_share", "NoiseFloor", "ReferenceFrame", "mean_flip", "noise_floor", "primary_rays",
           "relative_rmse", "relative_squared_errors", "render_reference", "SilhouetteError", "silhouette_error",
           "window_share"]
